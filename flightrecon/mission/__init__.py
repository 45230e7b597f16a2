"""The closed loop of active reconstruction (`loop.Mission`) and the policies it follows, one module each:
the take-off and first views (`launch`), the way out when no candidate is feasible (`recovery`), the
stopping rule (`stopping`), output.diagnose (`diagnosis`), what a flight writes (`outputs`), what the
loop carries between frames (`state`) and its progress bar (`progress`)."""

from flightrecon.mission.loop import Mission

__all__ = ["Mission"]
