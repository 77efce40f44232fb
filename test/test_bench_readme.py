"""`nao-skin bench --readme`: the results section and the plot land in the README, the rest stays."""
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
