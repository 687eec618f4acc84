"""A clone is the whole project (issue 18): no test skips for want of data, and no file of
the repository points at a path of the machine it was written on."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import MISSING_DATA_REASON

ROOT = Path(__file__).resolve().parents[1]
TESTS = ROOT / "tests"


# ---- no test skips for missing data ---------------------------------------------------------

_INNER_TESTS = '''
    import pytest

    @pytest.fixture
    def benchmark_dir():
        pytest.skip("official benchmark data not present")

    def test_data_skip_in_body():
        pytest.skip("Bouc-Wen benchmark data not found in /nowhere")

    @pytest.mark.skipif(True, reason="missing train.h5")
    def test_data_skipif_marker():
        pass

    def test_data_skip_in_fixture(benchmark_dir):
        pass

    def test_platform_skip():
        pytest.skip("needs Linux /proc")

    @pytest.mark.skipif(True, reason="~100 s; set CABLESVC_SLOW=1")
    def test_opt_in_skip():
        pass

    @pytest.mark.xfail(reason="known bug", strict=True)
    def test_known_bug():
        assert False

    def test_runs():
        assert True
'''
_DATA_SKIPS = ("test_data_skip_in_body", "test_data_skipif_marker", "test_data_skip_in_fixture")
_OTHER_SKIPS = ("test_platform_skip", "test_opt_in_skip")


def _inner_run(tmp_path: Path, with_conftest: bool) -> tuple[int, str]:
    (tmp_path / "test_inner.py").write_text(textwrap.dedent(_INNER_TESTS))
    if with_conftest:
        (tmp_path / "conftest.py").write_text((TESTS / "conftest.py").read_text())
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-rA", "-p", "no:cacheprovider", "test_inner.py"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    return proc.returncode, proc.stdout + proc.stderr


def test_a_skip_for_missing_data_fails_the_run(tmp_path):
    """The suite's conftest turns a skip that says data are missing (in the test body, by
    a skipif marker or in a fixture) into a failure; platform and opt-in skips and xfails
    stay as they are. Without the conftest the same file passes: the hook is what fails it."""
    (tmp_path / "hook").mkdir()
    (tmp_path / "plain").mkdir()
    rc, out = _inner_run(tmp_path / "hook", with_conftest=True)
    assert rc == 1, out
    for name in _DATA_SKIPS:
        assert re.search(rf"^(FAILED|ERROR) test_inner\.py::{name}\b", out, re.M), (name, out)
        assert f"{name} was skipped for missing data" in out
    for name in _OTHER_SKIPS:
        assert not re.search(rf"^(FAILED|ERROR) test_inner\.py::{name}\b", out, re.M), (name, out)
    assert re.search(r"^XFAIL test_inner\.py::test_known_bug", out, re.M), out
    assert re.search(r"^PASSED test_inner\.py::test_runs", out, re.M), out
    assert "2 skipped" in out

    rc0, out0 = _inner_run(tmp_path / "plain", with_conftest=False)
    assert rc0 == 0 and "5 skipped" in out0, out0


@pytest.mark.parametrize("reason, data", [
    ("Bouc-Wen benchmark data not found in /x", True),
    ("official benchmark data not present", True),
    ("missing train.h5", True),
    ("needs the dataset (set CABLESVC_DATA)", True),
    ("recording file does not exist", True),
    ("no /dev/full on this system", False),
    ("needs Linux /proc", False),
    ("needs the openssl command to make certificates", False),
    ("python-can's udp_multicast interface needs msgpack (python-can[multicast])", False),
    ("~100 s; set CABLESVC_SLOW=1", False),
])
def test_missing_data_reasons_are_told_from_other_skips(reason, data):
    assert bool(MISSING_DATA_REASON.search(reason)) is data


_EXISTS_CALL = re.compile(r"\.(exists|is_file|is_dir)\(|os\.path\.(exists|isfile|isdir)\(|\bdata_dir\(")
_SYSTEM_PATH = re.compile(r"""["'](/proc|/dev|/sys)(/|["'])""")


def _is_pytest_attr(node: ast.AST, *names: str) -> bool:
    """``pytest.<a>.<b>`` for names (a, b)."""
    for name in reversed(names):
        if not (isinstance(node, ast.Attribute) and node.attr == name):
            return False
        node = node.value
    return isinstance(node, ast.Name) and node.id == "pytest"


def data_conditioned_skips(source: str, filename: str = "<test>") -> list[str]:
    """Skips in a test source that depend on data being present: ``pytest.skip(...)`` under
    an ``if`` that tests a path's existence, ``pytest.mark.skipif(<exists test>, ...)``, or
    either with a reason that says data are missing. Existence tests of system paths
    (/proc, /dev, /sys) are platform checks, not data, and are allowed. Returns
    ``file:line: text`` for each."""
    tree = ast.parse(source, filename)
    parents: dict[ast.AST, ast.AST] = {}
    for node in ast.walk(tree):
        for child in ast.iter_child_nodes(node):
            parents[child] = node

    def seg(node):
        return ast.get_source_segment(source, node) or ""

    def data_condition(cond: str) -> bool:
        return bool(_EXISTS_CALL.search(cond)) and not _SYSTEM_PATH.search(cond)

    hits = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        if _is_pytest_attr(node.func, "skip"):
            reason = seg(node.args[0]) if node.args else ""
            cond, p = "", parents.get(node)
            while p is not None and not isinstance(p, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Module)):
                if isinstance(p, ast.If):
                    cond += " " + seg(p.test)
                p = parents.get(p)
        elif _is_pytest_attr(node.func, "mark", "skipif"):
            cond = seg(node.args[0]) if node.args else ""
            reason = " ".join(seg(k.value) for k in node.keywords if k.arg == "reason")
        else:
            continue
        if data_condition(cond) or MISSING_DATA_REASON.search(reason):
            hits.append(f"{filename}:{node.lineno}: {seg(node)}")
    return hits


def test_the_scan_finds_data_conditioned_skips():
    """The source scan below is able to fail: the ways a data skip is usually written are
    found, the platform and opt-in skips of this suite are not."""
    found = data_conditioned_skips(textwrap.dedent('''
        import os, pytest
        from pathlib import Path
        OFFICIAL = Path("somewhere/boucwen")
        needs = pytest.mark.skipif(not (OFFICIAL / "test.h5").exists(), reason="official data")

        def _dir():
            d = data_dir()
            if not (d / "train.h5").exists():
                pytest.skip(f"not here: {d}")
            return d

        @pytest.mark.skipif(not os.path.isfile("rec.mcap"), reason="x")
        def test_a(): pass

        def test_b():
            pytest.skip("benchmark data not found")
    '''))
    assert sorted(int(h.split(":")[1]) for h in found) == [5, 10, 13, 17], found
    assert data_conditioned_skips(textwrap.dedent('''
        import os, shutil, pytest
        from pathlib import Path
        pytestmark = pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux /proc")

        def test_full():
            if not os.path.exists("/dev/full"):
                pytest.skip("no /dev/full on this system")

        @pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")
        def test_tls(): pass

        @pytest.mark.skipif(not os.environ.get("CABLESVC_SLOW"), reason="~100 s; set CABLESVC_SLOW=1")
        def test_slow(): pass
    ''')) == []


def test_no_test_skips_for_missing_data_in_the_sources():
    """A skip conditioned on data never fires on a machine that has the data, so the
    runtime hook alone would only catch it in a clone: scan every test source too."""
    hits = []
    for path in sorted(TESTS.rglob("*.py")):
        hits += data_conditioned_skips(path.read_text(encoding="utf-8"), str(path.relative_to(ROOT)))
    assert hits == [], "tests skip when data are missing (ship the data instead):\n" + "\n".join(hits)


# ---- no machine paths -------------------------------------------------------------------------

#: Absolute paths of a development machine, and the sibling folder a clone does not have.
#: (Written with a character class so that this file does not match itself.)
MACHINE_PATH = re.compile(r"/wor[k]/|/hom[e]/[a-z]|/roo[t]/|\.\./share[d]\b")
SCANNED = ("cablesvc", "docs", "tests", "deploy", "README.md", "pyproject.toml")


def _text_files():
    for top in SCANNED:
        p = ROOT / top
        files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else []
        for f in files:
            if "__pycache__" in f.parts or ".egg-info" in str(f):
                continue
            data = f.read_bytes()
            if b"\0" in data[:8192]:          # binary (HDF5, numba caches, images)
                continue
            yield f, data.decode("utf-8", errors="replace")


def test_the_machine_path_pattern_matches_what_it_must():
    for s in ("/" + "work/shared/data/boucwen", "see ../" + "shared/papers/", "/" + "home/jm/rec.mcap",
              "/" + "root/.cache/x"):
        assert MACHINE_PATH.search(s), s
    for s in ("docs/references.md", "cablesvc/data/boucwen", "/tmp/x.mcap", "/etc/cablesvc/cablesvc.toml",
              "/var/lib/cablesvc", "network/"):
        assert not MACHINE_PATH.search(s), s


def test_no_absolute_machine_path_in_the_repository():
    """cablesvc/, docs/, tests/, deploy/, README.md and pyproject.toml name no path of the
    machine they were written on (see MACHINE_PATH: the work and home folders, root's home,
    the shared folder beside the checkout): a clone has none of them."""
    hits = []
    n = 0
    for f, text in _text_files():
        n += 1
        for i, line in enumerate(text.splitlines(), 1):
            if MACHINE_PATH.search(line):
                hits.append(f"{f.relative_to(ROOT)}:{i}: {line.strip()[:120]}")
    assert n > 50, f"only {n} text files scanned: wrong root {ROOT}?"
    assert hits == [], "machine paths in the repository:\n" + "\n".join(hits)
