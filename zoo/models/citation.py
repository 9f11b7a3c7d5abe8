"""Where a model comes from: its paper (authors, title, venue, year, a link) and its public code,
as a registry entry states them (``paper:``, ``code:``), and the BibTeX entry of that paper."""

from __future__ import annotations

import re
from typing import Annotated

import pydantic
from pydantic import AfterValidator, ConfigDict, Field, StrictInt, StringConstraints

# Title words a BibTeX key skips, as Google Scholar's keys do.
_SKIPPED = {"a", "an", "the", "on", "of", "for", "to", "in"}

Text = Annotated[str, StringConstraints(strip_whitespace=True, min_length=1)]


def _https(url: str) -> str:
    if not re.fullmatch(r"https://[^\s]+", url.strip()):
        raise ValueError(f"expected an https:// address, got {url!r}")
    return url.strip()


# An https address (a paper's DOI or arXiv page, a code repository).
Url = Annotated[str, AfterValidator(_https)]


def _one_line(title: str) -> str:
    return " ".join(title.split())


@pydantic.dataclasses.dataclass(frozen=True, config=ConfigDict(extra="forbid"))
class Paper:
    """A model's paper, as a registry entry's ``paper:`` writes it: ``booktitle`` (a conference),
    ``journal`` or neither (a preprint, its ``eprint`` an arXiv identifier); ``url`` a DOI,
    arXiv or open-archive address."""

    authors: Annotated[tuple[Text, ...], Field(min_length=1)]
    title: Annotated[Text, AfterValidator(_one_line)]
    year: Annotated[StrictInt, Field(ge=1900, le=2100)]
    url: Url
    booktitle: Text = ""
    journal: Text = ""
    eprint: Text = ""

    @pydantic.model_validator(mode="after")
    def _one_venue(self) -> Paper:
        if self.booktitle and self.journal:
            raise ValueError(
                "paper has both booktitle and journal: a conference paper names its booktitle, "
                "a journal article its journal"
            )
        return self

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


def _escaped(text: str) -> str:
    """``text`` with the characters LaTeX reads as commands escaped (``Computers & Graphics``)."""
    return re.sub(r"(?<!\\)([&%$#_])", r"\\\1", text)
