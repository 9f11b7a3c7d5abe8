"""The leaderboards as a static site (``zoo site``): :mod:`zoo.site.collect` reads what the
committed files hold, :mod:`zoo.site.build` writes the pages."""

from zoo.site.build import SiteBuild, build_site

__all__ = ["SiteBuild", "build_site"]
