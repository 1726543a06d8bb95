"""The docs stay a guide: short, linked, free of history outside the changelog, and in step with
the code they describe (the pages, the paths the code cites, the outputs, config.yaml)."""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = sorted((REPO / "docs").rglob("*.md"))
PAGES = [REPO / "README.md", *DOCS]
WORD_BUDGET = 20_000
LINK = re.compile(r"\]\(([^)\s]+)\)")
COMMIT = re.compile(r"(?<![\w/.-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w-])")
CITED_PAGE = re.compile(r"(?<![\w.])(?:docs|diagnostics)/[\w/.-]+?\.(?:md|png|py)")


def words(path: Path) -> int:
    return len(path.read_text().split())


def anchors(page: Path) -> set[str]:
    """GitHub's heading anchors: lower case, punctuation dropped, spaces to hyphens."""
    out = set()
    for line in page.read_text().splitlines():
        if line.startswith("#") and not line.startswith("#!"):
            text = line.lstrip("#").strip().lower()
            out.add(re.sub(r"[^\w\- ]", "", text).replace(" ", "-"))
    return out


def test_the_docs_fit_the_word_budget():
    total = sum(words(p) for p in DOCS)
    largest = sorted(((words(p), str(p.relative_to(REPO))) for p in DOCS), reverse=True)[:5]
    assert total <= WORD_BUDGET, f"docs/ holds {total:,} words (budget {WORD_BUDGET:,}): {largest}"


def test_no_commit_hash_outside_the_changelog():
    for page in PAGES:
        if page.name == "changelog.md":
            continue
        found = COMMIT.findall(page.read_text())
        assert not found, (
            f"{page.relative_to(REPO)} names commits {found}: history goes to the changelog"
        )


def test_every_relative_link_and_anchor_resolves():
    for page in PAGES:
        for target in LINK.findall(page.read_text()):
            if re.match(r"[a-z]+:", target):
                continue  # http(s), mailto
            path, _, anchor = target.partition("#")
            resolved = (page.parent / path).resolve() if path else page
            where = f"{page.relative_to(REPO)}: ({target})"
            assert resolved.exists(), f"{where}: no such file"
            if anchor and resolved.suffix == ".md":
                assert anchor in anchors(resolved), f"{where}: no such heading"


def test_every_docs_path_the_code_cites_exists():
    roots = ["src", "scripts", "rules", "workflow", "tests", "benchmarks", "diagnostics", "config"]
    files = [
        REPO / n for n in ("Snakefile", "Makefile", "config.yaml", "pyproject.toml", "README.md")
    ]
    for root in roots:
        if (REPO / root).is_dir():
            files += [
                p
                for p in (REPO / root).rglob("*")
                if p.is_file()
                and p.suffix in (".py", ".smk", ".yaml", ".yml", ".rst", ".md", ".toml", ".txt")
            ]
    missing = []
    for path in files:
        text = path.read_text(errors="replace")
        for m in CITED_PAGE.finditer(text):
            cited = m.group(0)
            anchor = re.match(r"#([\w-]+)", text[m.end() :])
            if "*" in cited:
                continue
            if not (REPO / cited).exists():
                missing.append(f"{path.relative_to(REPO)}: {cited}")
            elif anchor and cited.endswith(".md") and anchor.group(1) not in anchors(REPO / cited):
                missing.append(f"{path.relative_to(REPO)}: {cited}#{anchor.group(1)}")
    assert not missing, "\n".join(missing)


def test_config_yaml_is_short_with_one_line_comments():
    lines = (REPO / "config.yaml").read_text().splitlines()
    assert len(lines) <= 60, len(lines)
    comment_only = [i + 1 for i, line in enumerate(lines) if line.lstrip().startswith("#")]
    assert comment_only == [1], (
        f"config.yaml: comment-only lines {comment_only}; one per key, inline"
    )


def test_the_outputs_page_lists_every_file_the_workflow_names():
    from threedcal.study import paths as scenes

    page = (REPO / "docs/reference/outputs.md").read_text()
    normal = re.sub(r"\{[^}]*\}", "{}", page)
    paths = []
    for value in vars(scenes).values():
        values = value.values() if isinstance(value, dict) else [value]
        paths += [v for v in values if isinstance(v, str) and v.startswith("results/")]
    assert len(paths) > 40
    undocumented = []
    for path in paths:
        parent, _, leaf = re.sub(r"\{[^}]*\}", "{}", path).rpartition("/")
        stem = leaf.split(".")[0].replace("{}", "")
        if "/.partial/" in path or (parent not in normal) or (stem and stem not in page):
            undocumented.append(path)
    assert undocumented == [f"{scenes.SCENE}/.partial/raw.zarr"] or not undocumented, undocumented


def test_an_example_is_skipped_only_for_hardware():
    """Every other block runs in `make test` (on a small input, or as a dry run)."""
    hardware = ("printer", "camera", "video", "board", "serial", "/dev/")
    for page in PAGES:
        for reason in re.findall(r"<!-- docs-test: skip: (.*?) -->", page.read_text()):
            assert any(word in reason for word in hardware), f"{page.relative_to(REPO)}: {reason}"
