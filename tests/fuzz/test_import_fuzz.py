"""`jcalib import` under mutated inputs, per importer (issue 32): every answer is a message, never a crash
or a hang; nothing that existed changes; a failure leaves nothing behind; nothing outside the source
folder is read.

The data sets are the importer tests' layouts (tests/io/importers; camodocal's real example in
tests/data), tiny (16x12 images, 2-4 stations) so that each format's cases run in a few seconds; the
mutations and the checks are in ``import_fuzz.py`` (fixed seeds). No JAX compilation happens here.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from import_fuzz import FORMATS, cases, run_case

pytest.importorskip("rosbags")  # the rosbag seeds are written with rosbags' writers (the dev extra)


@pytest.mark.parametrize("fmt", FORMATS)
def test_mutated_imports_answer_with_a_message_and_change_nothing(fmt, tmp_path):
    failures = []
    seen_codes = set()
    for case in cases(fmt, tmp_path, seed=0):
        o = run_case(case)
        seen_codes.add(o.code)
        where = f"{case.variant} / {case.mutation}: exit {o.code}: {o.text.strip()[-300:]}"
        if o.code not in (0, 2, 3) or o.internal_error:
            failures.append(f"crash: {where}")
        if o.changed:
            failures.append(f"changed {o.changed[:5]}: {where}")
        if o.left_behind:
            failures.append(f"left {o.left_behind[:5]} behind: {where}")
        if o.canary_opened and not case.allow_outside:
            failures.append(f"read a file outside the source: {where}")
        if case.mutation == "none" and case.variant != "joints-bad":
            assert o.code == 0, where  # the seeds are valid
        refusable = case.mutation.startswith(("escape:", "out:", "option:")) and case.mutation not in (
            "out:empty-dir", "escape:absolute+allowed")
        if case.mutation == "out:inside-source" and not Path(case.args[1]).is_dir():
            refusable = False  # a new folder beside a single-file source (samples.yaml, calib.bag) changes nothing
        if refusable and o.code != 2:
            failures.append(f"accepted: {where}")
    assert not failures, "\n".join(failures)
    assert 2 in seen_codes and 0 in seen_codes


def test_allowed_outside_paths_are_followed(tmp_path):
    """``--option allow_outside=true``: the path outside the source is read (the canary opened)."""
    [case] = [c for c in cases("industrial-calibration", tmp_path) if c.mutation == "escape:absolute+allowed"]
    o = run_case(case)
    assert o.code == 0 and o.canary_opened, o.text
