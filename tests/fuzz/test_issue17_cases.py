"""Every file / CLI case of issue 17's "Crashes", "Silent wrong answers" and "Data loss" lists, run
through the real command line in-process: each must end with exit status 2 and a message naming
the problem (never a traceback), and before any solve; an output that names an input is refused
with the input unchanged.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from fuzz_files import CELL_YAML, observations
from fuzz_helpers import digest, run_cli

from jcalib.errors import NotObservableError


class SolveReached(NotObservableError):
    """Raised by the stub solve: the inputs passed every check (exit status 3)."""


@pytest.fixture(autouse=True)
def stub_solve(monkeypatch):
    """The calibration itself is replaced: the suite tests what happens before it, fast."""
    import importlib

    api = importlib.import_module("jcalib.problems.api")

    def solve(*args, **kwargs):
        raise SolveReached("stub solve reached")

    monkeypatch.setattr(api, "calibrate_cell", solve)
    monkeypatch.setattr(api, "reoptimise", solve)


def _write_obs(path: Path, mutate) -> None:
    data = observations()
    mutate(data)
    path.write_text(json.dumps(data, allow_nan=True))


def _write_cell(path: Path, mutate) -> None:
    data = yaml.safe_load(CELL_YAML)
    mutate(data)
    path.write_text(yaml.safe_dump(data))


def calibrate(inputs, tmp_path, *extra):
    return run_cli("calibrate", inputs["cell"], inputs["observations"], "-o", tmp_path / "out.json", *extra)


# ------------------------------------------------------------------------------ positive control


def test_valid_inputs_reach_the_solve(inputs, tmp_path):
    code, text = calibrate(inputs, tmp_path)
    assert code == 3 and "stub solve reached" in text, text


# --------------------------------------------------------------------------------- usage errors


@pytest.mark.parametrize(
    "args, needle",
    [
        (["calibrate", "--bogus"], "No such option"),
        (["calibrate"], "Missing argument"),
        (["export", "result.json"], "Missing option"),
        (["frobnicate"], "No such command"),
        (["calibrate", "c.yaml", "o.json", "-o", "r.json", "--sigma-px", "abc"], "--sigma-px"),
        (["calibrate", "c.yaml", "o.json", "-o"], "requires an argument"),
        (["detect", "--sesion", "x"], "No such option"),
    ],
)
def test_usage_errors_print_usage_and_exit_2(args, needle):
    code, text = run_cli(*args)
    assert code == 2 and needle in text, text
    assert "Usage:" in text or "requires an argument" in text, text


def test_version_and_help_exit_0():
    assert run_cli("--version")[0] == 0
    code, text = run_cli("calibrate", "--help")
    assert code == 0 and "OBSERVATIONS" in text.upper()


# ------------------------------------------------------------------------------------- crashes

OBS_CRASHES = {
    "camera entry is a list": (lambda d: d["cameras"].__setitem__("cam_hand", [640, 480]), "cameras.cam_hand"),
    "contacts is a list of names": (lambda d: d["stations"][-1].__setitem__("contacts", ["torch"]), "contacts"),
    "pixel of 1e300": (lambda d: d["stations"][0]["detections"][0]["pixels"][0].__setitem__(0, 1e300), "outside"),
    "pixel is NaN": (lambda d: d["stations"][0]["detections"][0]["pixels"][0].__setitem__(0, float("nan")), "NaN"),
    "pixel is infinite": (lambda d: d["stations"][1]["detections"][0]["pixels"][3].__setitem__(1, float("inf")),
                          "finite"),
    "pixel is a string": (lambda d: d["stations"][0]["detections"][0]["pixels"][0].__setitem__(0, "812.4"),
                          "expected a number"),
    "station is a string": (lambda d: d["stations"].__setitem__(0, "s000"), "stations[0]"),
    "detections is a mapping": (lambda d: d["stations"][0].__setitem__("detections", {"camera": "cam_hand"}),
                                "detections"),
    "T_base_flange 3x3": (lambda d: d["stations"][0].__setitem__("T_base_flange", np.eye(3).tolist()),
                          "T_base_flange"),
    "image_size as text": (lambda d: d["cameras"]["cam_hand"].__setitem__("image_size", "640x480"), "image_size"),
    "huge image_size": (lambda d: d["cameras"]["cam_hand"].__setitem__("image_size", [10**12, 480]), "image_size"),
    "top level is a list": (lambda d: (d.clear(), d.update({"schema": ["x"]})), "schema"),
    "integer with 5000 digits": (lambda d: None, "not valid JSON"),  # written below as raw text
}


@pytest.mark.parametrize("case", list(OBS_CRASHES))
def test_malformed_observations_exit_2(inputs, tmp_path, case):
    mutate, needle = OBS_CRASHES[case]
    _write_obs(inputs["observations"], mutate)
    if case == "integer with 5000 digits":
        inputs["observations"].write_text('{"schema": "jcalib.observations/1", "x": ' + "9" * 5000 + "}")
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and needle in text, text


CELL_CRASHES = {
    "tools entry is a list": (lambda d: d["tools"].__setitem__("torch", ["cam_fixed"]), "tools.torch"),
    "camera entry is a list": (lambda d: d["cameras"].__setitem__("cam_hand", [640, 480]), "cameras.cam_hand"),
    "dist of letters": (lambda d: d["cameras"]["cam_fixed"]["intrinsics"].__setitem__("dist", ["a", "b"]), "dist"),
    "cols is text": (lambda d: d["targets"]["board"].__setitem__("cols", "four"), "cols"),
    "K is 2x2": (lambda d: d["cameras"]["cam_fixed"]["intrinsics"].__setitem__("K", [[1, 0], [0, 1]]), "K"),
    "cell is a list": (lambda d: (d.clear(), d.update({"schema": 1})), "schema"),
    "giant board": (lambda d: d["targets"]["board"].update(cols=1000, rows=1000), "board"),
}


@pytest.mark.parametrize("case", list(CELL_CRASHES))
def test_malformed_cell_exit_2(inputs, tmp_path, case):
    mutate, needle = CELL_CRASHES[case]
    _write_cell(inputs["cell"], mutate)
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and needle in text, text


def _spoil_utf8(path: Path) -> None:
    data = path.read_bytes()
    i = data.index(b"cam_hand") if b"cam_hand" in data else len(data) // 2
    path.write_bytes(data[:i] + b"\xff\xfe" + data[i:])


def _commands(inputs, tmp_path) -> dict[str, list]:
    """A command that reads each kind of file (outputs in tmp_path)."""
    o = tmp_path / "out"
    return {
        "cell": ["calibrate", inputs["cell"], inputs["observations"], "-o", f"{o}.json"],
        "observations": ["calibrate", inputs["cell"], inputs["observations"], "-o", f"{o}.json"],
        "result": ["export", inputs["result"], "-f", "krl", "-o", f"{o}.dat"],
        "plan": ["capture", "--robot", "kuka://127.0.0.1:9", "--camera", "cam_hand=gige://127.0.0.1",
                 "--plan", inputs["plan"], "--out", f"{o}-session"],
        "pixels": ["triangulate", inputs["pixels"], "--cell", inputs["cell"], "--result", inputs["result"],
                   "-o", f"{o}.json"],
        "points": ["frame", inputs["points"], "-o", f"{o}.json"],
        "scenario": ["study", inputs["scenario"], "--trials", "1", "-o", f"{o}.csv"],
        "session.json": ["detect", "--session", inputs["session"], "-o", f"{o}.json"],
        "stations.jsonl": ["detect", "--session", inputs["session"], "-o", f"{o}.json"],
    }


def _file_of(inputs, kind: str) -> Path:
    return inputs["session"] / kind if kind in ("session.json", "stations.jsonl") else inputs[kind]


@pytest.mark.parametrize("kind", ["cell", "observations", "result", "plan", "pixels", "points", "scenario",
                                  "session.json", "stations.jsonl"])
def test_non_utf8_byte_in_any_input_exit_2(inputs, tmp_path, kind):
    path = _file_of(inputs, kind)
    _spoil_utf8(path)
    code, text = run_cli(*_commands(inputs, tmp_path)[kind])
    assert code == 2 and "not UTF-8" in text and "line" in text, text


@pytest.mark.parametrize("kind", ["cell", "observations", "result", "plan", "pixels", "points", "scenario",
                                  "session.json"])
@pytest.mark.parametrize("depth", [100, 100_000])
def test_deeply_nested_input_exit_2(inputs, tmp_path, kind, depth):
    path = _file_of(inputs, kind)
    path.write_text("[" * depth + "]" * depth)
    code, text = run_cli(*_commands(inputs, tmp_path)[kind])
    assert code == 2 and "nested" in text, text


def test_deeply_nested_station_line_exit_2(inputs, tmp_path):
    path = inputs["session"] / "stations.jsonl"
    path.write_text(path.read_text() + "[" * 50_000 + "]" * 50_000 + "\n")
    code, text = run_cli(*_commands(inputs, tmp_path)["stations.jsonl"])
    assert code == 2 and "nested" in text, text


BOMB = """schema: jcalib.cell/1
a: &a [x, x, x, x, x, x, x, x, x, x]
b: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]
c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]
d: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]
e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]
f: &f [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]
g: &g [*f, *f, *f, *f, *f, *f, *f, *f, *f, *f]
h: &h [*g, *g, *g, *g, *g, *g, *g, *g, *g, *g]
i: &i [*h, *h, *h, *h, *h, *h, *h, *h, *h, *h]
"""


@pytest.mark.parametrize("kind", ["cell", "plan", "scenario"])
def test_yaml_alias_bomb_exit_2(inputs, tmp_path, kind):
    path = _file_of(inputs, kind)
    if kind == "plan":
        path = path.with_suffix(".yaml")
        cmd = _commands(inputs, tmp_path)["plan"]
        cmd[cmd.index(inputs["plan"])] = path
    else:
        cmd = _commands(inputs, tmp_path)[kind]
    path.write_text(BOMB)
    code, text = run_cli(*cmd)
    assert code == 2 and "alias" in text and len(text) < 2000, text


def test_recursive_yaml_alias_exit_2(inputs, tmp_path):
    inputs["cell"].write_text("schema: jcalib.cell/1\ncameras: &a {x: *a}\n")
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and "alias" in text, text


def test_markup_in_names_and_paths_is_printed_plainly(inputs, tmp_path):
    # a camera id with rich markup: refused with the name shown as written
    _write_cell(inputs["cell"], lambda d: d["cameras"].__setitem__("c[/x]", {"model": "pinhole"}))
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and "c[/x]" in text, text
    # a path with markup in every command's error message
    for cmd in (["calibrate", "a[/x].yaml", inputs["observations"], "-o", tmp_path / "o[bold].json"],
                ["export", tmp_path / "[/x]r.json", "-f", "krl", "-o", tmp_path / "o.dat"],
                ["frame", tmp_path / "[red]p[/red].json", "-o", tmp_path / "o.json"]):
        code, text = run_cli(*cmd)
        assert code == 2 and "[/x]" in text or "[red]" in text, text
    # control characters in a path are escaped, not sent to the terminal
    code, text = run_cli("export", tmp_path / "r\x1b[31m.json", "-f", "krl", "-o", tmp_path / "o.dat")
    assert code == 2 and "\x1b" not in text and "\\x1b" in text, text


def _solve_not_reached(text: str) -> bool:
    return "stub solve reached" not in text


@pytest.mark.parametrize("where", ["directory", "under a file", "read-only", "missing folder", "device"])
def test_bad_output_refused_before_the_solve(inputs, tmp_path, where):
    out = {"directory": tmp_path,
           "under a file": inputs["cell"] / "result.json",
           "read-only": Path("/proc/jcalib-fuzz.json"),
           "missing folder": tmp_path / "no" / "such" / "result.json",
           "device": Path("/dev/null")}[where]
    code, text = run_cli("calibrate", inputs["cell"], inputs["observations"], "-o", out)
    assert code == 2 and _solve_not_reached(text), text


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header says width x height (the pixel data is never reached)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


def test_image_above_the_pixel_budget_is_refused_without_decoding(inputs, tmp_path):
    import resource

    big = tmp_path / "big.png"
    big.write_bytes(_png_header(20000, 20000))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    code, text = run_cli("detect", big, "--cell", inputs["cell"], "--camera", "cam_hand", "-o", tmp_path / "o.json")
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert code == 2 and "20000x20000" in text and "Mpx" in text, text
    assert grown_mb < 500, f"RSS grew by {grown_mb:.0f} MB"


def test_input_above_the_size_budget_is_refused(inputs, tmp_path, monkeypatch):
    monkeypatch.setenv("JCALIB_MAX_INPUT_MB", "0.001")
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and "MiB" in text and "JCALIB_MAX_INPUT_MB" in text, text


def test_fifo_input_is_refused_without_blocking(inputs, tmp_path):
    import os

    fifo = tmp_path / "cell.yaml"
    os.mkfifo(fifo)
    code, text = run_cli("calibrate", fifo, inputs["observations"], "-o", tmp_path / "o.json")
    assert code == 2 and "not a regular file" in text, text


# ------------------------------------------------------------------------------ silent wrong answers

SILENT_OBS = {
    "flange translations in millimetres": (
        lambda d: [st["T_base_flange"][r].__setitem__(3, st["T_base_flange"][r][3] * 1000)
                   for st in d["stations"] for r in range(3)], "millimetres"),
    "flange_poses in millimetres": (
        lambda d: d["stations"][0].update(flange_poses={"r1": (np.diag([1, 1, 1, 1.0]) + np.eye(4, k=3) * 600).tolist()},
                                          T_base_flange=None), "millimetres"),
    "detection of a camera the cell lacks": (
        lambda d: (d["cameras"].__setitem__("cam_extra", {"image_size": [640, 480]}),
                   d["stations"][0]["detections"].append(dict(d["stations"][0]["detections"][0], camera="cam_extra"))),
        "camera 'cam_extra' is not in the cell"),
    "detection of a target the cell lacks": (
        lambda d: (d["targets"].__setitem__("plate", d["targets"]["board"]),
                   d["stations"][0]["detections"].append(dict(d["stations"][0]["detections"][0], target="plate"))),
        "target 'plate' is not in the cell"),
    "tool tip of a tool the cell lacks": (
        lambda d: d["stations"][-1]["detections"][0].__setitem__("tool", "torch2"), "did you mean 'torch'"),
    "contact with a point the cell lacks": (
        lambda d: d["stations"][-1]["contacts"][0].__setitem__("point", "divit"), "did you mean 'divot'"),
    "image_size far smaller than the pixels": (
        lambda d: d["cameras"]["cam_hand"].__setitem__("image_size", [120, 90]), "far outside"),
    "image_size smaller than the pixels": (
        lambda d: d["cameras"]["cam_hand"].__setitem__("image_size", [320, 240]), "image_size is wrong"),
    "fractional point_index": (
        lambda d: d["stations"][0]["detections"][0]["point_index"].__setitem__(2, 1.5), "integer"),
    "target points in millimetres": (
        lambda d: d["targets"]["board"].__setitem__("points", (np.asarray(d["targets"]["board"]["points"])
                                                                * 1000).tolist()), "millimetres"),
    "target with other point count than the cell": (
        lambda d: (d["targets"]["board"]["points"].append([0.1, 0.1, 0.0])), "points"),
    "unknown station key": (lambda d: d["stations"][0].__setitem__("T_base_flang", None), "T_base_flange"),
    "unknown detection key": (lambda d: d["stations"][0]["detections"][0].__setitem__("pixel_index", []),
                              "did you mean 'point_index'"),
}


@pytest.mark.parametrize("case", list(SILENT_OBS))
def test_silent_wrong_answers_in_observations_exit_2(inputs, tmp_path, case):
    mutate, needle = SILENT_OBS[case]
    _write_obs(inputs["observations"], mutate)
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and needle in text and _solve_not_reached(text), text


SILENT_CELL = {
    "short dist": (lambda d: d["cameras"]["cam_fixed"]["intrinsics"].__setitem__("dist", [-0.12, 0.05, 0.0, 0.0]),
                   "5 distortion coefficients"),
    "long dist": (lambda d: d["cameras"]["cam_fixed"]["intrinsics"].__setitem__("dist", [0.0] * 8), "got 8"),
    "fixed typo": (lambda d: d.__setitem__("fixed", ["T_base_bord"]), "did you mean 'T_base_board'"),
    "fix typo": (lambda d: d["cameras"]["cam_fixed"]["fix"].append("k4"), "'k4' is not an intrinsic"),
    "unknown tool key": (lambda d: d["tools"]["torch"].__setitem__("obsrved_by", ["cam_fixed"]),
                         "did you mean 'observed_by'"),
    "unknown point key": (lambda d: d["points"]["divot"].__setitem__("positon", [0, 0, 0]), "did you mean 'position'"),
    "unknown camera key": (lambda d: d["cameras"]["cam_hand"].__setitem__("modle", "opencv5"), "did you mean 'model'"),
    "unknown top-level key": (lambda d: d.__setitem__("tool", {}), "did you mean 'tools'"),
    "square in millimetres": (lambda d: d["targets"]["board"].__setitem__("square", 25), "millimetres"),
    "camera pose in millimetres": (
        lambda d: d["cameras"]["cam_fixed"].__setitem__("pose", (np.eye(4) + np.eye(4, k=3) * 800).tolist()),
        "millimetres"),
    "observed_by typo": (lambda d: d["tools"]["torch"].__setitem__("observed_by", ["cam_fixd"]),
                         "did you mean 'cam_fixed'"),
    "mount typo": (lambda d: d["cameras"]["cam_hand"].__setitem__("mount", "flang"), "did you mean 'flange'"),
    "two things with one name": (lambda d: d["points"].__setitem__("board", {}), "name of a target"),
}


@pytest.mark.parametrize("case", list(SILENT_CELL))
def test_silent_wrong_answers_in_the_cell_exit_2(inputs, tmp_path, case):
    mutate, needle = SILENT_CELL[case]
    _write_cell(inputs["cell"], mutate)
    code, text = calibrate(inputs, tmp_path)
    assert code == 2 and needle in text and _solve_not_reached(text), text


def test_a_pixel_just_outside_the_image_gives_a_named_warning(inputs, tmp_path):
    _write_obs(inputs["observations"], lambda d: d["stations"][1]["detections"][0]["pixels"][3].__setitem__(0, 645.0))
    code, text = calibrate(inputs, tmp_path)
    assert code == 3 and "jcalib warning:" in text and "outside its 640x480 image" in text, text
    assert "station 's001'.detections[0].pixels[3]" in text, text


def test_target_points_off_the_cells_geometry_give_a_named_warning(inputs, tmp_path):
    _write_obs(inputs["observations"], lambda d: d["targets"]["board"].__setitem__(
        "points", (np.asarray(d["targets"]["board"]["points"]) * 1.01).tolist()))
    code, text = calibrate(inputs, tmp_path)
    assert code == 3 and "jcalib warning:" in text and "differ from the cell" in text, text


# --------------------------------------------------------------------------------------- data loss


def _loss_cases(inputs, tmp_path) -> list[tuple[str, list, Path]]:
    i = inputs
    s = i["session"]
    img = s / "images" / "cam_hand" / "s000.png"
    return [
        ("calibrate -o CELL", ["calibrate", i["cell"], i["observations"], "-o", i["cell"]], i["cell"]),
        ("calibrate -o OBS", ["calibrate", i["cell"], i["observations"], "-o", i["observations"]], i["observations"]),
        ("calibrate -o PRIOR", ["calibrate", i["cell"], i["observations"], "-o", i["result"], "--prior", i["result"]],
         i["result"]),
        ("triangulate -o PIXELS", ["triangulate", i["pixels"], "--cell", i["cell"], "-o", i["pixels"]], i["pixels"]),
        ("triangulate -o CELL", ["triangulate", i["pixels"], "--cell", i["cell"], "-o", i["cell"]], i["cell"]),
        ("triangulate -o RESULT", ["triangulate", i["pixels"], "--cell", i["cell"], "--result", i["result"], "-o",
                                   i["result"]], i["result"]),
        ("frame -o POINTS", ["frame", i["points"], "-o", i["points"]], i["points"]),
        ("frame --export-out POINTS", ["frame", i["points"], "-o", tmp_path / "f.json", "--export", "rapid",
                                       "--export-out", i["points"]], i["points"]),
        ("frame default export = input", [], i["points"]),
        ("report -o RESULT", ["report", i["result"], "-o", i["result"]], i["result"]),
        ("report -o OBS", ["report", i["result"], "--observations", i["observations"], "-o", i["observations"]],
         i["observations"]),
        ("report -o CELL", ["report", i["result"], "--cell", i["cell"], "-o", i["cell"]], i["cell"]),
        ("export -o RESULT", ["export", i["result"], "-f", "krl", "-o", i["result"]], i["result"]),
        ("detect -o IMAGE", ["detect", img, "--cell", i["cell"], "--camera", "cam_hand", "-o", img], img),
        ("detect -o CELL", ["detect", img, "--cell", i["cell"], "--camera", "cam_hand", "-o", i["cell"]], i["cell"]),
        ("detect --session -o session.json", ["detect", "--session", s, "-o", s / "session.json"], s),
        ("detect --session -o stations.jsonl", ["detect", "--session", s, "-o", s / "stations.jsonl"], s),
        ("detect --session -o an image", ["detect", "--session", s, "-o", img], s),
        ("detect --session -o CELL", ["detect", "--session", s, "--cell", i["cell"], "-o", i["cell"]], i["cell"]),
        ("plan -o CELL", ["plan", "--cell", i["cell"], "--kind", "handeye", "-o", i["cell"]], i["cell"]),
        ("study -o SCENARIO", ["study", i["scenario"], "-o", i["scenario"]], i["scenario"]),
        ("simulate --truth CELL", ["simulate", "--cell", i["cell"], "--robot-protocol", "kuka", "--robot-port", "0",
                                   "--camera", "cam_hand=127.0.0.1", "--truth", i["cell"]], i["cell"]),
        ("capture --out PLAN", ["capture", "--robot", "kuka://127.0.0.1:9", "--camera", "cam_hand=gige://127.0.0.1",
                                "--plan", i["plan"], "--out", i["plan"]], i["plan"]),
        ("capture --out CELL", ["capture", "--robot", "kuka://127.0.0.1:9", "--camera", "cam_hand=gige://127.0.0.1",
                                "--plan", i["plan"], "--cell", i["cell"], "--out", i["cell"]], i["cell"]),
    ]


LOSS_IDS = [c[0] for c in _loss_cases({k: Path(k) for k in ("cell", "observations", "result", "pixels", "points",
                                                               "scenario", "plan", "session")}, Path("."))]


@pytest.mark.parametrize("case", LOSS_IDS)
def test_output_naming_an_input_is_refused_and_the_input_unchanged(inputs, tmp_path, case):
    name, cmd, protected = next(c for c in _loss_cases(inputs, tmp_path) if c[0] == case)
    if case == "frame default export = input":  # the default --export-out is -o with .mod: that is the input
        protected = inputs["points"].with_suffix(".mod")
        protected.write_text(inputs["points"].read_text())
        cmd = ["frame", protected, "-o", protected.with_suffix(".json"), "--export", "rapid"]
    before = digest(protected)
    code, text = run_cli(*cmd)
    assert code == 2 and ("input" in text or "same file" in text), text
    assert digest(protected) == before


def test_a_hard_link_or_symlink_to_an_input_is_an_input(inputs, tmp_path):
    import os

    link, sym = tmp_path / "link.yaml", tmp_path / "sym.yaml"
    os.link(inputs["cell"], link)
    os.symlink(inputs["cell"], sym)
    before = digest(inputs["cell"])
    for out in (link, sym):
        code, text = run_cli("calibrate", inputs["cell"], inputs["observations"], "-o", out)
        assert code == 2 and "input" in text, text
    assert digest(inputs["cell"]) == before


def test_valid_inputs_pass_every_command(inputs, tmp_path):
    """The checks refuse what is wrong, not everything: each command runs on the valid files."""
    o = tmp_path
    for fmt, extra in (("krl", []), ("rapid", []), ("opencv", ["--camera", "cam_hand"]),
                       ("ros", ["--camera", "cam_hand"])):
        code, text = run_cli("export", inputs["result"], "-f", fmt, "-o", o / f"e.{fmt}", *extra)
        assert code == 0, text
    code, text = run_cli("frame", inputs["points"], "-o", o / "frame.json", "--export", "krl")
    assert code == 0 and (o / "frame.dat").is_file(), text
    code, text = run_cli("triangulate", inputs["pixels"], "--cell", inputs["cell"], "--result", inputs["result"],
                         "-o", o / "tri.json")
    assert code in (0, 3), text  # 3: the two made-up rays may not meet in front of the camera
    code, text = run_cli("detect", "--session", inputs["session"], "-o", o / "obs.json")
    assert code == 2 and "found in no image" in text, text  # the session's images are blank
    code, text = run_cli("capture", "--robot", "kuka://127.0.0.1:9", "--camera", "cam_hand=gige://127.0.0.1",
                         "--plan", inputs["plan"], "--out", o / "session")
    assert code == 4, text  # the inputs pass; no robot answers on port 9
