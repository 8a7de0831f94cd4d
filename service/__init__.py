"""The HTTP/WebSocket service (FastAPI + uvicorn) built on :mod:`model`. Not written yet: see issue 5."""
