"""The example notebook (docs/notebook.ipynb) runs headless from start to end
and shows what it promises: a live render, the result as an image, the
trade-off plots and two settings side by side."""

from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs"


def test_example_notebook_runs():
    nbformat = pytest.importorskip("nbformat", reason="running notebooks needs pip install 'clpt[notebook]'")
    nbclient = pytest.importorskip("nbclient", reason="running notebooks needs pip install 'clpt[notebook]'")
    pytest.importorskip("ipykernel", reason="running notebooks needs pip install 'clpt[notebook]'")
    nb = nbformat.read(DOCS / "notebook.ipynb", as_version=4)
    for cell in nb.cells:  # what is stored is not what is checked
        if cell.cell_type == "code":
            cell.outputs = []
    # The kernel inherits this session's environment, and with it the isolated build cache.
    nbclient.NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(DOCS)}}
                            ).execute()
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert not [o for c in code for o in c.outputs if o.output_type == "error"]

    def data(cell):
        return [o.get("data", {}) for o in cell.outputs]

    live = data(code[1])  # the progress line and the image, each updated in place to its last state
    assert any("done: 256/256 spp" in d.get("text/html", "") for d in live)
    assert any("image/png" in d for d in live)
    assert any("image/png" in d and "RenderResult 96x96, 256 spp" in d.get("text/plain", "") for d in data(code[2]))
    assert sum("image/png" in d for d in data(code[3])) == 2  # the two trade-off plots
    assert "Pareto front" in "".join(o.get("text", "") for o in code[3].outputs)
    html = "".join(d.get("text/html", "") for d in data(code[4]))
    assert html.count("<img") == 3 and html.count("relMSE") == 2
