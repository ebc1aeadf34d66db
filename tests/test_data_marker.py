"""The data-test discipline of tests/conftest.py: every test reading a third-party mesh is marked ``data``."""

import pytest

from .conftest import data_mesh_path


def test_unmarked_test_reading_a_data_mesh_fails_with_the_fix():
    with pytest.raises(pytest.fail.Exception, match=r"mark it @pytest\.mark\.data"):
        data_mesh_path("elephant-50kv.off")


@pytest.mark.data
def test_marked_test_gets_the_path_or_a_skip_naming_the_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("MESHDENOISE_DATA", str(tmp_path))
    monkeypatch.delenv("MESHDENOISE_REQUIRE_DATA", raising=False)
    with pytest.raises(pytest.skip.Exception, match=f"nefertiti.off not found in {tmp_path}"):
        data_mesh_path("nefertiti.off")
    monkeypatch.setenv("MESHDENOISE_REQUIRE_DATA", "1")
    with pytest.raises(pytest.fail.Exception, match="MESHDENOISE_REQUIRE_DATA is set"):
        data_mesh_path("nefertiti.off")
    (tmp_path / "nefertiti.off").write_text("OFF\n0 0 0\n")
    assert data_mesh_path("nefertiti.off") == tmp_path / "nefertiti.off"


@pytest.mark.parametrize("mesh", ["elephant", "grid"])
def test_a_parameter_naming_a_data_fixture_marks_the_test(request, mesh):
    assert (request.node.get_closest_marker("data") is not None) == (mesh == "elephant")


def test_an_unmarked_test_sees_an_empty_data_folder_as_on_a_clone_without_the_meshes():
    """What lets CI's second pass run only ``-m data``: every other test already ran on the first pass with
    MESHDENOISE_DATA an empty folder and MESHDENOISE_REQUIRE_DATA unset (subprocesses included)."""
    import os
    import subprocess
    import sys

    from meshdenoise.data import data_dir, data_file

    from .conftest import no_data_folder

    assert os.environ["MESHDENOISE_DATA"] == no_data_folder() and str(data_dir()) == no_data_folder()
    assert data_dir().is_dir() and not any(data_dir().iterdir())
    assert "MESHDENOISE_REQUIRE_DATA" not in os.environ
    with pytest.raises(FileNotFoundError, match="elephant-50kv.off"):
        data_file("elephant-50kv.off")
    seen = subprocess.run([sys.executable, "-c", "from meshdenoise.data import data_dir; print(data_dir())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    assert seen == no_data_folder()


@pytest.mark.data
def test_a_marked_test_sees_the_data_folder_it_was_given():
    import os

    from .conftest import no_data_folder

    assert os.environ.get("MESHDENOISE_DATA") != no_data_folder()


def test_an_unmarked_test_skipping_for_want_of_the_empty_data_folder_is_a_failure():
    from .conftest import data_skip_as_failure, no_data_folder

    reason = f"elephant-50kv.off not found in {no_data_folder()}"
    assert "must be marked @pytest.mark.data" in data_skip_as_failure(False, reason)
    assert data_skip_as_failure(True, reason) is None  # a marked test may skip there (CI's second pass)
    assert data_skip_as_failure(False, "needs root to give the folder away") is None  # any other skip stands
