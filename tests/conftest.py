"""Suite-wide rules.

No test may skip for want of data (issue 18): everything the tests read ships with the
repository (e.g. the Bouc-Wen benchmark data in ``cablesvc/data/boucwen``), so a skip whose
reason says data or a file is missing would let the test command pass without testing.
:func:`pytest_runtest_makereport` turns such a skip into a failure that says so. Skips for
the platform (no ``/proc``, no ``/dev/full``), an optional tool or module, or an opt-in slow
test are left alone. ``tests/test_clone_standalone.py`` checks this hook and also scans
the test sources for data-conditioned skips that do not fire on a machine that has the data.

:func:`pytest_sessionstart` byte-compiles the package once: many tests start ``cablesvc``
subprocesses, and with ``PYTHONDONTWRITEBYTECODE`` set (as on the development and CI
machines) an editable install's modules were compiled again in every one of them
(tests/test_robustness_cli.py: 57 s without the cache, 40 s with it).

The suite runs in pytest-xdist worker processes (``addopts`` in pyproject.toml), two on a
2-core machine. Each worker, and every process a test starts from it, uses one BLAS thread
(:func:`cablesvc.threads.one_blas_thread`, the rule of the project's own worker pools): two
workers that each start one OpenBLAS thread per core spin against each other.
"""

from __future__ import annotations

import compileall
import os
import re
from pathlib import Path

import pytest

if os.environ.get("PYTEST_XDIST_WORKER"):
    # before any test module loads numpy, so that its OpenBLAS starts with one thread
    from cablesvc.threads import one_blas_thread
    one_blas_thread()

_DATA_WORD = r"(?:data(?:set)?s?|benchmark|files?|recordings?|[\w./-]*\.(?:h5|hdf5|mcap|csv|npz|npy|mat|json|toml))"
_MISSING_WORD = (r"(?:not found|not present|missing|absent|unavailable|not available|does not exist|"
                 r"doesn't exist|no such|not there|not downloaded|not installed)")

#: A skip reason that says data or a file is missing ("benchmark data not found in DIR",
#: "official benchmark data not present", "missing train.h5", "needs the dataset", ...).
MISSING_DATA_REASON = re.compile(
    rf"\b{_DATA_WORD}\b.{{0,80}}?\b{_MISSING_WORD}"
    rf"|\b(?:missing|no|without|needs?|requires?)\b.{{0,40}}?\b{_DATA_WORD}(?:\W|$)",
    re.IGNORECASE,
)


def skip_reason(report: pytest.TestReport) -> str:
    """The text of a skipped report's reason (``Skipped: `` prefix removed)."""
    lr = report.longrepr
    text = lr[2] if isinstance(lr, tuple) and len(lr) == 3 else str(lr or "")
    return text[len("Skipped: "):] if text.startswith("Skipped: ") else text


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo):
    outcome = yield
    rep = outcome.get_result()
    if not rep.skipped or hasattr(rep, "wasxfail"):
        return
    reason = skip_reason(rep)
    if MISSING_DATA_REASON.search(reason):
        rep.outcome = "failed"
        rep.longrepr = (f"{item.nodeid} was skipped for missing data ({reason!r}): the data a test "
                        f"needs must ship with the repository, so this test has to run (issue 18)")


@pytest.fixture(scope="module")
def robot():
    """The IPAnema 3 robot (robots/ipanema3.toml), loaded once per test module: the robot
    most tests run on. A module about another robot (planar4, a simulated fleet's robot)
    defines its own ``robot`` fixture, which overrides this one there."""
    from cablesvc.config import load_robot
    return load_robot("ipanema3")


def pytest_sessionstart(session: pytest.Session) -> None:
    import cablesvc

    # py_compile writes the cache whatever PYTHONDONTWRITEBYTECODE says; an interpreter with
    # that variable set still reads it (and recompiles any module whose source changed)
    compileall.compile_dir(str(Path(cablesvc.__file__).resolve().parent), quiet=2)
