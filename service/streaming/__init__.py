"""WebSocket streaming (``/v1/stream``, docs/protocol.md): the per-connection message protocol, each
connection's outgoing queue, the per-model scheduler that steps every streamed character in batches
with the commands connections send it, and the frame encodings."""
