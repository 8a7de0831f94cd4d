"""The HTTP/WebSocket service (FastAPI + uvicorn) built on :mod:`model`: ``service.app.create_app``; docs/service.md.

Layout: ``app`` assembles the application from ``routes`` (one module per group of endpoints) and
``http`` (what every request passes through: API keys, rate limit, body cap, request timing, logs);
``streaming`` holds the WebSocket protocol, connections, the per-model scheduler and frame encodings;
``viewer`` the web viewer's page and takes. Beside them: ``settings`` (the only reader of ``RSMT_*``),
``registry`` (loaded models and their threads), ``engine_jobs`` and ``motion`` (engine calls and payload
conversion), ``errors`` (the error envelope and the engine's errors as contract codes), ``schemas``,
``state``, ``lifecycle``, ``warmup`` and ``metrics``.
"""
