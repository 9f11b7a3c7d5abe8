"""Leaderboards: a benchmark's tables brought up to date or checked against a fresh
computation (:mod:`.board`, :mod:`.check`), the rounding a check tolerates (:mod:`.rounding`),
and the cost columns (:mod:`.efficiency` measures, :mod:`.costs` stores). It imports report and
every layer below it; only the commands and the site stand above it."""
