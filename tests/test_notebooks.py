import json
from pathlib import Path

import pytest
from matplotlib.figure import Figure

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_and_ends_in_a_figure(path):
    """Notebooks hold no logic, only calls into jaxcls: their code cells must run against the current API."""
    cells = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
    namespace: dict = {}
    for cell in cells[:-1]:
        exec("".join(cell["source"]), namespace)
    *body, last = "".join(cells[-1]["source"]).splitlines()
    exec("\n".join(body), namespace)
    result = eval(last, namespace)
    assert isinstance(result, Figure) and len(result.axes) >= 2
