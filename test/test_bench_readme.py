"""`nao-skin bench --readme`: the results blocks and the plot land in the file named (the project's: docs/results.md),
the rest stays."""
from pathlib import Path

import pytest

from nao_skin.commands.bench import README_END, README_PLOT, README_START, update_readme
from nao_skin.errors import DataError


def test_results_section_is_replaced_and_plot_copied(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "bench_results.md").write_text("# nao-skin bench\n\n## Speed against error\n\n| a | b |\n\n"
                                          "![speed against error](speed_vs_error.png)\n")
    (out / "speed_vs_error.png").write_bytes(b"\x89PNG fake")
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n\n{README_START}\nold table\n{README_END}\n\noutro\n")
    update_readme(readme, out)
    text = readme.read_text()
    assert text.startswith("intro\n") and text.rstrip().endswith("outro")
    assert "old table" not in text and "### Speed against error" in text and f"]({README_PLOT})" in text
    assert (tmp_path / README_PLOT).read_bytes() == b"\x89PNG fake"


def test_readme_without_markers_is_one_clear_error(tmp_path):
    (tmp_path / "out").mkdir()
    readme = tmp_path / "README.md"
    readme.write_text("no section here\n")
    with pytest.raises(DataError, match="README.md"):
        update_readme(readme, tmp_path / "out")


def test_a_kinematics_run_fills_its_own_block_and_leaves_the_main_one(tmp_path):
    from nao_skin.commands.bench import README_KIN_END, README_KIN_START

    out = tmp_path / "out"
    out.mkdir()
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{README_START}\nmain tables\n{README_END}\nmiddle\n"
                      f"{README_KIN_START}\nold kinematics\n{README_KIN_END}\noutro\n")
    (out / "bench_results.md").write_text("# nao-skin bench\n\nCommand: `nao-skin bench --only kinematics`\n\n"
                                          "## Kinematics\n\n| preset | kinematics |\n\nBenchmark wall time: 9 s.\n")
    update_readme(readme, out)
    text = readme.read_text()
    assert "main tables" in text and "old kinematics" not in text and "middle" in text
    kin = text.split(README_KIN_START)[1].split(README_KIN_END)[0]
    assert kin.strip().splitlines() == ["Command: `nao-skin bench --only kinematics`", "", "### Kinematics", "",
                                        "| preset | kinematics |", "", "Benchmark wall time: 9 s."]
    # a whole run: the kinematics to their block, everything else to the main one
    (out / "bench_results.md").write_text("# nao-skin bench\n\nCommand: `nao-skin bench`\n\n## Speed against error"
                                          "\n\n| a |\n\n## Kinematics\n\n| k |\n\nBenchmark wall time: 99 s.\n")
    update_readme(readme, out)
    text = readme.read_text()
    main = text.split(README_START)[1].split(README_END)[0]
    kin = text.split(README_KIN_START)[1].split(README_KIN_END)[0]
    assert "### Speed against error" in main and "| k |" not in main and "Benchmark wall time: 99 s." in main
    assert "| k |" in kin and "| a |" not in kin and kin.strip().startswith("Command: `nao-skin bench`")


ROOT = Path(__file__).resolve().parents[1]


def test_the_project_keeps_its_bench_results_in_docs_results_md():
    """``--readme`` alone writes the project's results file, docs/results.md: it holds both blocks, with the plot
    beside it (the README itself links there and has no bench block any more)."""
    from nao_skin.cli import build_parser
    from nao_skin.commands.bench import README_KIN_END, README_KIN_START, RESULTS_DOC

    assert RESULTS_DOC == "docs/results.md"
    args = build_parser().parse_args(["bench", "--out", "out/bench", "--readme", "--force"])
    assert args.readme == RESULTS_DOC and args.force
    assert build_parser().parse_args(["bench", "--out", "o", "--readme", "my.md"]).readme == "my.md"
    text = (ROOT / RESULTS_DOC).read_text()
    for start, end in ((README_START, README_END), (README_KIN_START, README_KIN_END)):
        assert text.count(start) == 1 and text.count(end) == 1 and text.index(start) < text.index(end)
    assert f"]({README_PLOT})" in text and (ROOT / RESULTS_DOC).with_name(README_PLOT).is_file()
    readme = (ROOT / "README.md").read_text()
    assert README_START not in readme and README_KIN_START not in readme and RESULTS_DOC in readme
