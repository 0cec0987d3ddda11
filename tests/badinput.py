"""Helpers of the bad-input and fault suite (a test helper, not a test).

A refused command must write nothing and change nothing: :func:`tree` takes a snapshot of
folders (every file's SHA-1, every folder, every symbolic link and file mode) so a test can
compare it before and after; :func:`refused` runs a command's ``main`` in-process that way and
returns its exit code and message.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]


def tree(*roots: str | os.PathLike) -> dict[str, str]:
    """``{path: what}`` of everything under ``roots`` (hidden entries included): a file's mode
    and SHA-1, ``dir`` and its mode, or the target of a symbolic link."""
    out: dict[str, str] = {}
    for root in roots:
        root = Path(root)
        if not root.exists() and not root.is_symlink():
            out[str(root)] = "absent"
            continue
        paths = [root] + sorted(root.rglob("*")) if root.is_dir() else [root]
        for p in paths:
            if p.is_symlink():
                out[str(p)] = f"link -> {os.readlink(p)}"
            elif p.is_dir():
                out[str(p)] = f"dir {oct(p.stat().st_mode)}"
            else:
                out[str(p)] = f"{oct(p.stat().st_mode)} {hashlib.sha1(p.read_bytes()).hexdigest()}"
    return out


def refused(main, argv: list[str], capsys, *roots) -> tuple[int, str]:
    """Run ``main(argv)`` (a command's entry point) and check that it changed nothing under
    ``roots``; returns (exit code, stderr). ``SystemExit`` (argparse's errors) counts as its
    code; any other exception (a traceback for the user) fails the test."""
    before = tree(*roots)
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    captured = capsys.readouterr()
    err = captured.err
    after = tree(*roots)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"the refused command wrote or changed {changed[:5]}"
    assert "Traceback" not in err
    return code, err


def write_images(folder: Path, n: int = 6, size=(64, 48), seed: int = 0, ext: str = "png"
                 ) -> Path:
    """``n`` random colour images into ``folder`` (created)."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    for i in range(n):
        cv2.imwrite(str(folder / f"img_{i:02d}.{ext}"),
                    (rng.random((size[1], size[0], 3)) * 255).astype(np.uint8))
    return folder


def case_registry():
    """A table of bad-input cases and its decorator: ``CASES, case = case_registry()``, then
    ``@case("needle", ...)`` on a function ``(tmp_path) -> argv`` registers it under its name
    with the words its message must hold."""
    cases: dict = {}

    def case(*needles):
        def register(fn):
            cases[fn.__name__] = (fn, needles)
            return fn
        return register

    return cases, case

