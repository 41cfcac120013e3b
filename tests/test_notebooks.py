"""Notebooks run top to bottom (small shot counts; notebook 02 reads back the snow study the
bench run of this test run made, where it ran first: conftest's ``snow_study_file``)."""
import pathlib

import nbformat
import pytest
from nbclient import NotebookClient

NOTEBOOKS = sorted((pathlib.Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_runs(path, monkeypatch, snow_study_file):
    monkeypatch.setenv("QUICKSTART_SHOTS", "300")
    if snow_study_file.is_file():    # the snow study test_bench.py's bench run made (conftest)
        monkeypatch.setenv("SNOW_STUDY_JSON", str(snow_study_file))
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
