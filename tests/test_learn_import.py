"""torch stays optional: the core imports without it and the learning modules say how to install it."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def _run(code: str) -> subprocess.CompletedProcess:
    # sys.modules["torch"] = None makes every `import torch` raise ImportError, as if it were not installed.
    prelude = "import sys\nsys.modules['torch'] = None\n"
    return subprocess.run([sys.executable, "-c", prelude + textwrap.dedent(code)], capture_output=True, text=True,
                          timeout=120)


def test_core_imports_without_torch():
    res = _run("""
        import latticeopt, latticeopt.design
        import latticeopt.learn, latticeopt.learn.metrics, latticeopt.learn.splits
        latticeopt.learn.split_indices(10)
        print("ok")
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_cli_parser_builds_without_torch():
    res = _run("""
        from latticeopt.cli import build_parser
        build_parser()
        print("ok")
    """)
    assert res.returncode == 0, res.stderr


def test_learning_modules_name_the_install_command_without_torch():
    res = _run("""
        import latticeopt.learn as L
        for name in ("latticeopt.learn.recon_net", "latticeopt.learn.training", "latticeopt.learn.classifiers"):
            try:
                __import__(name)
            except L.MissingDependencyError as exc:
                from latticeopt._extras import install_command
                assert install_command("learn") in str(exc), exc
                assert isinstance(exc, ImportError)
            else:
                raise SystemExit(f"{name} imported without torch")
        try:
            L.ReconNet
        except L.MissingDependencyError:
            print("ok")
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"


def test_importing_latticeopt_does_not_import_torch():
    res = subprocess.run([sys.executable, "-c", "import sys, latticeopt, latticeopt.design, latticeopt.learn, "
                          "latticeopt.learn.metrics; print('torch' in sys.modules)"],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "False"


def test_metrics_name_the_install_command_without_scikit_image():
    res = _run("""
        sys.modules["skimage"] = sys.modules["skimage.metrics"] = None
        import numpy as np
        from latticeopt.learn import MissingDependencyError
        from latticeopt.learn.metrics import classification_report, evaluate_images
        classification_report(np.array([0, 1]), np.array([0, 1]), ["a", "b"])  # numpy only: works
        try:
            evaluate_images(np.eye(16), np.eye(16))
        except MissingDependencyError as exc:
            from latticeopt._extras import install_command
            assert "scikit-image" in str(exc) and install_command("learn") in str(exc), exc
            print("ok")
    """)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "ok"
