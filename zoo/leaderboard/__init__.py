"""Leaderboards: a benchmark's tables planned (:mod:`.plan`: the rows of each table and what a run
does with each), then brought up to date (:mod:`.rebuild`) or checked against a fresh
computation (:mod:`.check`, judged by :mod:`.verdict` within the rounding :mod:`.rounding`
measures); and the cost columns (:mod:`.efficiency` measures, :mod:`.costs` stores). It imports
report and every layer below it; only the commands and the site stand above it."""
