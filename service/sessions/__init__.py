"""One WebSocket connection's session of ``/v1/stream`` (docs/protocol.md): the messages it reads and answers
(:mod:`~service.sessions.protocol`) and the budgets a flood of them runs into (:mod:`~service.sessions.message_budget`),
over the streaming machinery (:mod:`service.streaming`) they drive."""
