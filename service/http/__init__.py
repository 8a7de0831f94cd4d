"""What every HTTP request passes through before or around its route: API keys and the per-key rate limit,
the request body cap, request timing, and the log format (of the service and of uvicorn)."""
