"""Output folders (idp.fs): what cannot be one is said with the path, before anything is created."""

import pytest

from idp.errors import OutputError
from idp.fs import make_output_dir, output_dir_problem


def test_a_folder_or_a_new_path_can_be_an_output_folder(tmp_path):
    assert output_dir_problem(tmp_path) is None
    assert output_dir_problem(tmp_path / "new" / "deeper") is None
    assert make_output_dir(tmp_path / "new" / "deeper").is_dir()


def test_a_file_cannot(tmp_path):
    (tmp_path / "f").write_text("x")
    assert "is a file" in (output_dir_problem(tmp_path / "f") or "")
    assert "is a file" in (output_dir_problem(tmp_path / "f" / "below") or "")
    with pytest.raises(OutputError, match="is a file"):
        make_output_dir(tmp_path / "f")


@pytest.mark.parametrize("name", ["\x00", "a\x00b"])
def test_a_name_with_a_nul_character_is_an_error_not_a_traceback(tmp_path, name):
    # found by the CLI fuzz test: `idp uv IN.obj --report '\x00'` ended in ValueError from os.mkdir
    assert "NUL" in (output_dir_problem(tmp_path / name) or "")
    with pytest.raises(OutputError, match="NUL"):
        make_output_dir(tmp_path / name)
    assert list(tmp_path.iterdir()) == []
