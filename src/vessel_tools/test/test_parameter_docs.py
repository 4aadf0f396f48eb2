"""config/parts/*.yaml and the table of docs/parameters.md are what the nodes' parameter tables write."""

from pathlib import Path

import yaml

from vessel_common.parameter_names import flatten
from vessel_tools import parameter_docs

REPO = Path(__file__).resolve().parents[3]


def test_the_part_files_and_the_reference_are_written_from_the_tables():
    stale = parameter_docs.stale_files(REPO)
    assert not stale, f"run ./vessel params render: {[str(path.relative_to(REPO)) for path in stale]} differ"


def test_every_node_table_reads_back_from_its_part_file():
    for table in parameter_docs.node_tables():
        part = yaml.safe_load((REPO / "config" / "parts" / f"{table.node}.yaml").read_text())
        values = flatten(part[table.node]["ros__parameters"])
        assert values.keys() == table.defaults().keys()
        assert all(repr(values[name]) == repr(default) for name, default in table.defaults().items())


def test_check_names_a_drifted_file_and_render_mends_it(tmp_path, capsys):
    (tmp_path / "config" / "parts").mkdir(parents=True)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "parameters.md").write_text("# Parameters\n\nHand-written text stays.\n")
    assert parameter_docs.main(["render", "--check", "--root", str(tmp_path)]) == 1
    assert "tracker.yaml differs" in capsys.readouterr().err
    assert parameter_docs.main(["render", "--root", str(tmp_path)]) == 0
    assert parameter_docs.main(["render", "--check", "--root", str(tmp_path)]) == 0
    text = (tmp_path / "docs" / "parameters.md").read_text()
    assert text.startswith("# Parameters\n\nHand-written text stays.\n") and "| tracker | `min_score` |" in text
    part = tmp_path / "config" / "parts" / "tracker.yaml"
    part.write_text(part.read_text().replace("min_score: 0.0", "min_score: 0.5"))
    assert parameter_docs.main(["render", "--check", "--root", str(tmp_path)]) == 1


def test_the_reference_lists_every_parameter_once_with_its_live_flag():
    text = (REPO / "docs" / "parameters.md").read_text()
    for table in parameter_docs.node_tables():
        for param in table:
            row = f"| {table.node} | `{param.name}` |"
            assert text.count(row) == 1, row
            line = next(line for line in text.splitlines() if line.startswith(row))
            assert f"| {'yes' if param.live else 'no'} |" in line
