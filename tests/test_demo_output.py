"""What ``make demo`` prints: the package's warnings as one line each, like the command line,
not Python's "file:line: Category: ..." with the source line under it."""

import warnings

from lpvpc import demo
from lpvpc.errors import LpvpcWarning, PhysiologyWarning


def test_the_demo_prints_a_package_warning_as_one_line(monkeypatch, capsys):
    def run(outdir):  # the demo's steps replaced by one that warns as identify does
        warnings.warn("no confidence intervals for this model", LpvpcWarning, stacklevel=2)
        warnings.warn("reflex gain is negative", PhysiologyWarning, stacklevel=2)
        return 0

    monkeypatch.setattr(demo, "run", run)
    assert demo.main(["unused"]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines() == ["warning: no confidence intervals for this model", "warning: reflex gain is negative"]
    assert "LpvpcWarning" not in out + err and ".py:" not in out + err
