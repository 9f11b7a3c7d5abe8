"""What a reader sees: a leaderboard's tables (:mod:`.tables`), the files a table's folder
holds and the index of every table (:mod:`.outputs`), model cards (:mod:`.cards`), rendered
motion (:mod:`.render`) and the site's clips (:mod:`.clips`). It imports stats and the layers
below it; it never writes a number it did not read."""
