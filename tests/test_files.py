"""prismstereo.files: whole files only, and the temporary files a killed writer leaves found again."""

import pytest

from prismstereo import io
from prismstereo.files import partial_stem, replacing


def test_replacing_renames_a_whole_file_and_removes_a_failed_one(tmp_path):
    path = tmp_path / "new" / "depth.npy"
    with replacing(path) as partial:
        assert partial.parent == path.parent and partial.suffix == ".npy" and partial_stem(partial) == "depth"
        partial.write_bytes(b"whole")
    assert path.read_bytes() == b"whole"
    with pytest.raises(OSError, match="disk full"), replacing(path) as partial:
        partial.write_bytes(b"half")
        raise OSError("disk full")
    assert path.read_bytes() == b"whole" and sorted(p.name for p in path.parent.iterdir()) == ["depth.npy"]


def test_partial_stem_and_the_io_names():
    assert partial_stem(".clip_000003.4711.partial.png") == "clip_000003" and partial_stem("clip.png") is None
    assert partial_stem(".a.b.12.partial") == "a.b"
    assert io.replacing is replacing and io.partial_stem is partial_stem
