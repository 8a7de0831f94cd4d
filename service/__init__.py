"""The HTTP/WebSocket service (FastAPI + uvicorn) built on :mod:`model`: ``service.app.create_app``; docs/service.md."""
