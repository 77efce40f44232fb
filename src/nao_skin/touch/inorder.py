"""The sensor streams back in the order of their stamps, however they arrive.

Each stream (a topic: the joint states, one part's taxels, one part's contacts) arrives in its own order, but
not in step with the others: a recorder held up for seconds (a busy machine, a slow disk, a stopped process)
gets each topic's backlog when DDS delivers or repairs it, one topic up to seconds after another, and a
stream bag (``ros2 bag record``) holds them as its recorder got them. The touch detector makes a moment of
the parts' samples as it reads them, so read out of step it loses touches without a word (docs/decisions.md,
"A recorder held up for seconds"). :class:`InOrder` merges the streams by stamp. A message goes on once
every stream heard from in the last ``forget`` s has a message waiting (none of them can still bring an
earlier one), or once a message has waited ``wait`` s since it arrived (a stream that is quiet for a while,
as a driver that sends only while pressed, holds the others up no longer than that). Each stream keeps its
own order, whatever its stamps: a mis-stamped message is the detector's to judge, as before.
"""
from __future__ import annotations

from collections import deque
from typing import Hashable

#: s a message waits for the other streams' earlier ones: well above Fast DDS' heartbeat period (3 s), within
#: which a reliable reader that fell behind has a topic's backlog repaired, and as long as the topics' queues
#: hold (nodes.topics.STREAM_DEPTH). Only a quiet stream makes anything wait that long
WAIT_S = 10.0
#: s after its last message a stream is no longer waited for (a driver stopped): longer than a recorder may
#: be held up and still find the messages of the meantime in the topics' queues (nodes.topics.STREAM_DEPTH)
FORGET_S = 30.0


class InOrder:
    """``push(stream, stamp, arrived, item)`` returns the items that may go on, in stamp order (ties in
    arrival order); ``ready(now)`` those whose wait ran out with no message since; ``drain()`` the rest.
    ``arrived`` and ``now`` are one clock: the live recorder's, or a bag's newest stamp read so far."""

    def __init__(self, wait: float = WAIT_S, forget: float = FORGET_S):
        self.wait, self.forget = wait, forget
        self._queues: dict = {}      # stream -> deque of (stamp, arrival number, arrived, item)
        self._last: dict = {}        # stream -> arrival time of its last message
        self._n = 0

    def push(self, stream: Hashable, stamp: float, arrived: float, item) -> list:
        queue = self._queues.get(stream)
        if queue is None:
            queue = self._queues[stream] = deque()
        queue.append((stamp, self._n, arrived, item))
        self._last[stream] = arrived
        self._n += 1
        return self.ready(arrived)

    def ready(self, now: float) -> list:
        out = []
        while True:
            first = None
            every, overdue = True, False
            for stream, queue in self._queues.items():
                if not queue:
                    every = every and now - self._last[stream] > self.forget
                    continue
                head = queue[0]
                overdue = overdue or now - head[2] >= self.wait
                if first is None or head[:2] < first[0][:2]:
                    first = queue
            if first is None or not (every or overdue):
                return out
            out.append(first.popleft()[3])

    def drain(self) -> list:
        return self.ready(float("inf"))

    def __len__(self) -> int:
        """How many messages wait."""
        return sum(len(queue) for queue in self._queues.values())
