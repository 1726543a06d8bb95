"""The sections of the results page and of results/summary.md, one module a topic: each holds the
page's section (`..._section`, every scene in one table) and the summary's lines or facts of one
scene (`..._lines`, `..._facts`), so that the two documents read one set of builders."""
