import json
from pathlib import Path

import pytest
from matplotlib.figure import Figure

NOTEBOOKS = sorted((Path(__file__).parent.parent / "notebooks").glob("*.ipynb"))


def _python(source: list[str] | str) -> str:
    """A cell's code without IPython magics (``%matplotlib inline``): plain Python runs it here."""
    return "\n".join(line for line in "".join(source).splitlines() if not line.lstrip().startswith("%"))


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_runs_and_ends_in_a_figure(path):
    """Notebooks hold no logic, only calls into jaxcls: their code cells must run against the current API,
    and they are saved with their outputs, the last cell's figure as an image."""
    cells = [c for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "code"]
    saved = [o.get("data", {}) for o in cells[-1].get("outputs", [])]
    assert any("image/png" in data for data in saved), (
        f"{path.name}: the last code cell has no saved image/png output; execute the notebook and save it "
        "with its outputs (jupyter nbconvert --to notebook --execute --inplace)")
    namespace: dict = {}
    for cell in cells[:-1]:
        exec(_python(cell["source"]), namespace)
    *body, last = _python(cells[-1]["source"]).splitlines()
    exec("\n".join(body), namespace)
    result = eval(last, namespace)
    assert isinstance(result, Figure) and len(result.axes) >= 2
