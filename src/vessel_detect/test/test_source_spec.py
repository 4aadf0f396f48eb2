"""source_spec: what a source string names, and the errors for one that names nothing usable."""

import pytest

from vessel_common.errors import DataError
from vessel_detect import source_spec
from vessel_fixtures import detect_synthetic as synthetic


def test_source_argument_errors(tmp_path):
    with pytest.raises(DataError, match="no source given"):
        source_spec.open_source("")
    with pytest.raises(DataError, match="start offset"):
        synthetic.write_bag(tmp_path / "bag", frames=2)
        source_spec.open_source(tmp_path / "bag", start_offset_s=-1.0)
    (tmp_path / "one.jpg").write_bytes(synthetic.frame_jpeg(0))
    with pytest.raises(DataError, match="single image"):
        source_spec.open_source(tmp_path / "one.jpg")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="has no images"):
        source_spec.open_source(tmp_path / "empty")
