"""Figures of recorded runs: reading a recording (:mod:`.recording`), where the camera looked (:mod:`.views`)
and the matplotlib figures (:mod:`.figures`)."""
