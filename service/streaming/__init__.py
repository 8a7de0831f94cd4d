"""WebSocket streaming (``/v1/stream``, docs/protocol.md): each connection's outgoing queue, the per-model
scheduler that steps every streamed character in batches with the commands connections send it, and the frame
encodings; the session that reads a connection's messages stands above it (:mod:`service.sessions`)."""
