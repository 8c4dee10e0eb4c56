"""The interactive simulation: the session that steps a scene (:mod:`.session`), the window
that draws it (:mod:`.window`) and the recorded input events (:mod:`.events`)."""
