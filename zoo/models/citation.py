"""Where a model comes from: its paper (authors, title, venue, year, a link) and its public code,
as a registry entry states them (``paper:``, ``code:``), and the BibTeX entry of that paper."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from zoo.core.errors import ZooError

_PAPER_KEYS = {"authors", "title", "year", "url", "booktitle", "journal", "eprint"}
_URL = re.compile(r"https://[^\s]+")
# Title words a BibTeX key skips, as Google Scholar's keys do.
_SKIPPED = {"a", "an", "the", "on", "of", "for", "to", "in"}


class CitationError(ZooError, ValueError):
    """A registry entry's ``paper`` or ``code`` field that is not what it must be."""


@dataclass(frozen=True)
class Paper:
    """A model's paper: ``booktitle`` (a conference), ``journal`` or neither (a preprint, its
    ``eprint`` an arXiv identifier); ``url`` a DOI, arXiv or open-archive address."""

    authors: tuple[str, ...]
    title: str
    year: int
    url: str
    booktitle: str = ""
    journal: str = ""
    eprint: str = ""

    @property
    def key(self) -> str:
        """``mao2019learning``: the first author's surname, the year, the first title word."""
        surname = re.sub(r"[^a-z]", "", self.authors[0].split()[-1].lower())
        words = [w for w in re.findall(r"[a-z0-9]+", self.title.lower()) if w not in _SKIPPED]
        return f"{surname}{self.year}{words[0] if words else ''}"

    def bibtex(self) -> str:
        kind = "inproceedings" if self.booktitle else "article" if self.journal else "misc"
        fields = [
            ("author", " and ".join(self.authors)),
            ("title", "{" + self.title + "}"),  # braces keep its capitals (MSR-GCN, 3D)
            ("booktitle", self.booktitle),
            ("journal", self.journal),
            ("year", str(self.year)),
            ("eprint", self.eprint),
            ("archivePrefix", "arXiv" if self.eprint else ""),
            ("url", self.url),
        ]
        body = "".join(
            f"  {name} = {{{value if name == 'url' else _escaped(value)}}},\n"
            for name, value in fields
            if value
        )
        return f"@{kind}{{{self.key},\n{body}}}"


def parse_paper(raw: Any, where: str) -> Paper | None:
    """The ``paper:`` field of a registry entry (``where`` names it in an error), or None."""
    if raw is None:
        return None
    if not isinstance(raw, dict):
        raise CitationError(f"{where}: field 'paper' must be a mapping of {_expected()}")
    unknown = sorted(set(raw) - _PAPER_KEYS)
    if unknown:
        raise CitationError(
            f"{where}: paper: unknown field(s) {', '.join(map(str, unknown))}; {_expected()}"
        )
    authors = raw.get("authors")
    if (
        not isinstance(authors, list)
        or not authors
        or not all(isinstance(a, str) and a.strip() for a in authors)
    ):
        raise CitationError(f"{where}: paper.authors must be a list of full names, got {authors!r}")
    for name in ("title", "booktitle", "journal", "eprint"):
        if name in raw and not (isinstance(raw[name], str) and raw[name].strip()):
            raise CitationError(f"{where}: paper.{name} must be text, got {raw[name]!r}")
    if "title" not in raw:
        raise CitationError(f"{where}: paper.title is required")
    if "booktitle" in raw and "journal" in raw:
        raise CitationError(
            f"{where}: paper has both booktitle and journal: a conference paper names its "
            f"booktitle, a journal article its journal"
        )
    year = raw.get("year")
    if not isinstance(year, int) or isinstance(year, bool) or not 1900 <= year <= 2100:
        raise CitationError(f"{where}: paper.year must be a year like 2022, got {year!r}")
    return Paper(
        authors=tuple(a.strip() for a in authors),
        title=" ".join(raw["title"].split()),
        year=year,
        url=parse_url(raw.get("url"), f"{where}: paper.url"),
        booktitle=raw.get("booktitle", ""),
        journal=raw.get("journal", ""),
        eprint=raw.get("eprint", ""),
    )


def parse_url(raw: Any, where: str) -> str:
    """An https address (a paper's DOI or arXiv page, a code repository)."""
    if not isinstance(raw, str) or not _URL.fullmatch(raw.strip()):
        raise CitationError(f"{where} must be an https:// address, got {raw!r}")
    return raw.strip()


def _escaped(text: str) -> str:
    """``text`` with the characters LaTeX reads as commands escaped (``Computers & Graphics``)."""
    return re.sub(r"(?<!\\)([&%$#_])", r"\\\1", text)


def _expected() -> str:
    return (
        "authors (a list), title, year, url (https://...), and booktitle (a conference), "
        "journal, or eprint (an arXiv identifier)"
    )
