"""Do the skin and the joints share a clock? Each stream's stamps against the time its messages arrive.

The recorder pairs a touch with the joint angles at the skin message's stamp. The skin's stamps come
from skinManager's host (the YARP envelope), the joints' from the PC that reads NAOqi: when those two
clocks differ by seconds, every touch silently takes the arm pose of another moment, and the joint
tolerance cannot tell, since joint states arrive all the time. On one machine, or with synchronised
clocks, a message arrives a few milliseconds after its stamp whatever its stream; a stream whose
arrival lag differs from the joints' by much more than that is stamped by another clock.
"""
from __future__ import annotations

from collections import deque

import numpy as np

# s: a skin stream lagging the joint states by more than this is on another clock (transport and
# processing delays are milliseconds; a touch is held still for longer than this, so a smaller
# difference does not matter)
SKEW_LIMIT_S = 0.25
WINDOW = 50                 # messages per stream the arrival lag is taken over
MIN_MESSAGES = 10           # a stream's lag is judged only after this many messages
LAG_PERCENTILE = 10         # the lag of a window's promptest tenth (see ArrivalLags)


class ArrivalLags:
    """Per stream, a low percentile (:data:`LAG_PERCENTILE`) of (arrival time - stamp) over its last
    :data:`WINDOW` messages.

    Not the median: a message that waits in a queue (a busy executor at start-up, a burst) arrives
    late whatever its clock, and a stream whose messages all queued for a while would look stamped
    by another clock (seen: joint states 0.4-0.8 s "ahead" of every skin topic on one machine while
    the session started). Queueing only ever adds to a lag; another clock shifts all of them. The
    promptest messages of a window show the clock, and a percentile rather than the minimum keeps a
    stray stamp from the future from deciding it.
    """

    def __init__(self, window: int = WINDOW):
        self._lags: dict = {}
        self._window = window

    def add(self, stream: str, stamp: float, arrival: float) -> None:
        lags = self._lags.get(stream)
        if lags is None:
            lags = self._lags[stream] = deque(maxlen=self._window)
        lags.append(arrival - stamp)

    def lag(self, stream: str) -> float | None:
        """The stream's arrival lag (s) of its promptest messages, or None before :data:`MIN_MESSAGES`."""
        lags = self._lags.get(stream)
        return (float(np.percentile(lags, LAG_PERCENTILE)) if lags is not None and len(lags) >= MIN_MESSAGES
                else None)

    def skew(self, reference: str) -> dict:
        """``{stream: its lag minus the reference stream's}`` (s) for every other stream with a lag:
        positive when its stamps are older than the reference's for messages that arrive together."""
        ref = self.lag(reference)
        if ref is None:
            return {}
        return {s: lag - ref for s in self._lags if s != reference and (lag := self.lag(s)) is not None}
