"""Statistics over stored results: intervals and the bold rule (:mod:`.intervals`), paired
comparisons of rows (:mod:`.comparison`), how much a table's ranking hangs on its protocol
(:mod:`.sensitivity`) and which rows a table ranks (:mod:`.ranking`). It reads results and
computes nothing from a model; it imports evaluation, protocol and core."""
