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
