"""The batches a scheduler steps, per pace and per API key: its *lanes*.

With per-key step shares off (:mod:`service.streaming.step_shares`) every character has the owner ``""``
and a pace has one lane without a size limit: one batch per pace, as before. With them on, each key's
characters of a pace fill lanes of at most ``rows`` characters (``RSMT_STEP_SHARE_BATCH``), so a key's
few characters never wait on another key's batch, and a key's very many step as several batches. A
character joins the least full lane of its key and pace (a new one when all are full); a lane left
empty is dropped (but the first lane of owner ``""``).

Owned by the scheduler's step thread, like the batches themselves.
"""

from __future__ import annotations

from model.inference.engine import Character, CharacterBatch, Engine
from service.streaming.step_length import smoothed
from service.streaming.stream import PACES


class Lanes:
    """Every lane of one model's scheduler, which lane each stepped character is in, and how long each steps."""

    def __init__(self, engine: Engine, rows: int | None = None) -> None:
        if rows is not None and rows < 1:
            raise ValueError(f"a lane must hold at least one character, got {rows}")
        self.engine = engine
        self.rows = rows
        self._lanes: dict[tuple[str, str], list[CharacterBatch]] = {(p, ""): [CharacterBatch(engine)] for p in PACES}
        self._of: dict[int, CharacterBatch] = {}  # id(character) -> its lane, while it is in one
        self._turn: dict[tuple[str, str], int] = {}  # round robin over one key's lanes of a pace
        self._seconds: dict[int, float] = {}  # id(lane) -> its running step length

    def first(self, pace: str) -> CharacterBatch:
        """The lane of owner ``""`` (every character's, with shares off)."""
        return self._lanes[(pace, "")][0]

    def add(self, ch: Character, pace: str, owner: str) -> CharacterBatch:
        """Put a character in the least full lane of its key and pace with room (a new lane if none has)."""
        lanes = self._lanes.setdefault((pace, owner), [])
        room = [b for b in lanes if self.rows is None or len(b) < self.rows]
        if room:
            lane = min(room, key=len)
        else:
            lane = CharacterBatch(self.engine)
            lanes.append(lane)
        lane.add(ch)
        self._of[id(ch)] = lane
        return lane

    def lane_of(self, ch: Character) -> CharacterBatch | None:
        """The lane a character steps in; None when it is in none (parked, or never added)."""
        return self._of.get(id(ch))

    def detach(self, ch: Character) -> CharacterBatch | None:
        """Take a character out of its lane, its state kept (``CharacterBatch.detach``); returns the lane."""
        lane = self._of.pop(id(ch), None)
        if lane is not None:
            lane.detach(ch)
            self._tidy()
        return lane

    def forget(self, chars: list[Character]) -> None:
        """Characters a lane dropped (``CharacterBatch.drop_finished``) are in no lane any more."""
        for ch in chars:
            self._of.pop(id(ch), None)
        self._tidy()

    def withdraw(self, ch: Character) -> bool:
        """Take out a character that is waiting to join its lane (added, never stepped): no restack, nothing
        kept. False (and nothing done) when it is a member already, or in no lane."""
        lane = self._of.get(id(ch))
        if lane is None or ch in lane.members:
            return False
        lane.remove(ch)
        self.forget([ch])
        return True

    def sweep(self) -> list[Character]:
        """Drop the members of every lane whose members have all ended (arrived or cancelled): nothing is left
        to step there, and dropping them all costs no restack. Returns the characters dropped. Without this, the
        lanes of a key that stopped stepping would hold its last characters' state until it came back."""
        dropped: list[Character] = []
        for lanes in self._lanes.values():
            for lane in lanes:
                if lane.members and all(m.done for m in lane.members):
                    dropped += lane.drop_finished()  # leaves no member: no restack
        if dropped:
            self.forget(dropped)
        return dropped

    def owners(self, pace: str) -> list[str]:
        """The keys with characters in a lane of ``pace``."""
        return sorted({owner for (p, owner), lanes in self._lanes.items() if p == pace and any(map(len, lanes))})

    def of(self, pace: str, owner: str) -> list[CharacterBatch]:
        """The non-empty lanes of one key and pace."""
        return [b for b in self._lanes.get((pace, owner), []) if len(b)]

    def in_turn(self, pace: str, owner: str) -> list[CharacterBatch]:
        """The key's non-empty lanes of ``pace``, starting one further on at each call (round robin): the
        first is the one whose turn it is to step."""
        lanes = self.of(pace, owner)
        if not lanes:
            return []
        turn = self._turn.get((pace, owner), 0) % len(lanes)
        self._turn[(pace, owner)] = turn + 1
        return lanes[turn:] + lanes[:turn]

    def replace(self, lane: CharacterBatch) -> list[Character]:
        """A lane that failed to step is emptied (a fresh batch in its place); returns its characters."""
        chars = list(lane.members)
        for ch in chars:
            self._of.pop(id(ch), None)
        for lanes in self._lanes.values():
            for i, b in enumerate(lanes):
                if b is lane:
                    lanes[i] = CharacterBatch(self.engine)
        self._seconds.pop(id(lane), None)
        self._tidy()
        return chars

    def record(self, lane: CharacterBatch, seconds: float) -> None:
        self._seconds[id(lane)] = smoothed(self._seconds.get(id(lane)), seconds)

    def seconds(self, lane: CharacterBatch) -> float:
        """The lane's running step length (0 before its first step)."""
        return self._seconds.get(id(lane), 0.0)

    def __len__(self) -> int:
        """How many lanes there are, empty first lanes included."""
        return sum(len(lanes) for lanes in self._lanes.values())

    def _tidy(self) -> None:
        """Drop empty lanes, but the first lane of owner ``""`` of each pace."""
        for key, lanes in list(self._lanes.items()):
            kept = [b for i, b in enumerate(lanes) if len(b) or (key[1] == "" and i == 0)]
            for b in lanes:
                if b not in kept:
                    self._seconds.pop(id(b), None)
            if kept:
                self._lanes[key] = kept
            else:
                del self._lanes[key]
                self._turn.pop(key, None)
