"""A model's paper and code in its registry entry, and the BibTeX written from them."""

import re

import pytest

from zoo.models.citation import Paper
from zoo.models.registry import Registry, RegistryError, load_registry


def test_bibtex_of_a_conference_paper_a_journal_article_and_a_preprint():
    ltd = load_registry().get("ltd").paper
    assert ltd.bibtex() == (
        "@inproceedings{mao2019learning,\n"
        "  author = {Wei Mao and Miaomiao Liu and Mathieu Salzmann and Hongdong Li},\n"
        "  title = {{Learning Trajectory Dependencies for Human Motion Prediction}},\n"
        "  booktitle = {ICCV},\n"
        "  year = {2019},\n"
        "  url = {https://arxiv.org/abs/1908.05436},\n"
        "}"
    )
    journal = Paper(("Ada Byron",), "The Graphs", 2023, "https://x.org/1", journal="A & B_1")
    assert journal.bibtex().startswith("@article{byron2023graphs,\n")
    assert "  journal = {A \\& B\\_1},\n" in journal.bibtex()  # LaTeX would read & as a column
    preprint = Paper(("A. N. Other",), "On a Model", 2025, "https://x.org/2", eprint="2507.1")
    assert preprint.key == "other2025model"
    assert "@misc{" in preprint.bibtex() and "  archivePrefix = {arXiv},\n" in preprint.bibtex()


def test_every_model_from_a_paper_links_it_and_its_code():
    registry = load_registry()
    for name in registry.list_models():
        entry = registry.get(name)
        if name in ("constant_velocity", "interpolate"):  # baselines no paper's figures follow
            continue
        if name == "tfan":  # public code with no paper found (docs/models/tfan.md)
            assert entry.paper is None and entry.code.startswith("https://github.com/")
            continue
        assert entry.paper is not None and entry.code.startswith("https://github.com/"), name
        assert entry.paper.url.startswith(("https://arxiv.org/abs/", "https://hal.science/"))
        # the free-text reference names the same authors, in the same order
        surnames = [a.split()[-1] for a in entry.paper.authors]
        cited = re.search(r"([A-Z][\w-]+(?:, [A-Z][\w-]+)*)\. ", entry.reference)
        assert cited and cited.group(1).split(", ") == surnames, name


@pytest.mark.parametrize(
    "paper, said",
    [
        ("paper: {title: T, year: 2020, url: https://a.org}", "field 'paper.authors' is required"),
        (
            "paper: {authors: [A B], year: 2020, url: https://a.org}",
            "field 'paper.title' is required",
        ),
        (
            "paper: {authors: [A B], title: T, year: '20', url: https://a.org}",
            "field 'paper.year': input should be a valid integer, got '20'",
        ),
        (
            "paper: {authors: [A B], title: T, year: 2020, url: a.org}",
            "field 'paper.url': expected an https:// address, got 'a.org'",
        ),
        (
            "paper: {authors: [A B], title: T, year: 2020, url: https://a.org, doi: 1}",
            "unknown field 'paper.doi'",
        ),
        ("paper: [A B]", "field 'paper': input should be a dictionary"),
        ("code: github.com/a/b", "field 'code': expected an https:// address"),
        (
            "paper: {authors: [A], title: T, year: 2020, url: https://a.org, journal: J, "
            "booktitle: C}",
            "both booktitle and journal",
        ),
    ],
)
def test_a_bad_paper_or_code_field_is_one_line_naming_it(tmp_path, paper, said):
    path = tmp_path / "mine.yaml"
    path.write_text(f"models:\n  x:\n    class: a.B\n    representation: joints\n    {paper}\n")
    with pytest.raises(RegistryError) as caught:
        Registry.from_files(path)
    message = str(caught.value)
    assert message.startswith(f"{path}, line 5: model 'x'") and said in message
    assert "\n" not in message
