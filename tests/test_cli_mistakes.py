"""A newcomer's mistakes through the `courtloc` command: every one is answered with one line on stderr naming
what was wrong, a non-zero exit and no traceback; `-v` adds the traceback. A few run as real processes (the
entry point, its exit code, the commands that join a bus and leave zenoh's threads behind); the rest go
through `courtloc.cli.exit_status`, the path the entry point takes up to its exit, in this process."""
from __future__ import annotations

import subprocess
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from buskit import PYTHON, endpoint, free_port
from cli_in_process import Finished, courtloc_in_process

# One or more per verb and per kind of mistake. (verb words and arguments, a
# word the line must contain). {tmp}, {data}, {nobody}, {five}, {cut}, {notonnx}, {text} are filled in below:
# a scratch folder, a small labelled dataset, an endpoint no router listens on, a 5-byte file, a recording
# cut short after its magic, a text file named model.onnx, and a text file.
MISTAKES: list[tuple[str, str]] = [
    ("nosuchverb", "nosuchverb"),
    # missing, unreadable or wrong-kind files
    ("eval --data {tmp}/missing", "missing"),
    ("eval --data {data} --model {tmp}/missing.onnx", "missing.onnx"),
    ("bench localize --package {tmp}/missing", "missing"),
    ("bench paper --model a={tmp}/missing.onnx --data {data}", "missing.onnx"),
    ("bench pipeline --config {tmp}/missing.toml", "missing.toml"),
    ("secure sign {text} --key {tmp}/missing.key", "missing.key"),
    ("replay {five}", "MCAP"),
    ("replay {text} --info", "MCAP"),
    ("replay {cut} --info", "MCAP"),
    ("bench localize --package {notonnx}", "ONNX"),
    ("bench localize --idle-ms -1", "--idle-ms"),
    ("eval --data {data} --model {notonnx}", "ONNX"),
    ("run camera --config {text}", "README"),
    ("up --config {tmp}/missing.toml", "missing.toml"),
    ("preprocess {text}", "README"),
    ("calibrate --data {data} --csv {tmp}/missing.csv --court seed-gazebo", "missing.csv"),
    ("shooter fit {tmp}/missing.csv", "missing.csv"),
    ("shooter rpm 3 --table {text}", "README"),
    ("model push {tmp}/missing.onnx", "missing.onnx"),
    ("train --data {tmp}/missing --out {tmp}/run", "missing"),
    ("export {tmp}/missing.pt --out {tmp}/onnx", "missing.pt"),
    ("localizer crosseval --data {tmp}/missing --json -", "missing"),
    ("localizer residuals --data {data} --model {tmp}/missing", "missing"),
    ("doctor --config {tmp}/missing.toml", "missing.toml"),
    ("bench fusion --package {tmp}/missing", "missing"),
    ("up --config {tmp}", "directory"),
    ("up --model-store {text} --duration 1", "not a folder"),
    ("bench twin --court {text} --scenario clean", "--court"),
    ("bench twin --config {tmp}/missing.toml --scenario clean", "missing.toml"),
    ("bench sweep --seeds one-two --scenario clean", "--seeds"),
    ("bench sweep --timings every --scenario clean", "--timings"),
    ("bench sweep --scenario nowhere", "nowhere"),
    ("bench sweep --court robocon2025 --camera seed-gazebo --scenario clean", "--camera"),
    ("export rosbag2 {tmp}/missing.mcap {tmp}/bag", "missing.mcap"),
    ("export rosbag2 {five} {tmp}", "exists"),
    ("calibrate intrinsics --images {tmp} --out {tmp}/c.json", "--board"),
    ("calibrate mount --court seed-gazebo --camera seed-gazebo --pose 1,2 --frames {tmp}", "X,Y,YAW"),
    # no router
    ("model list --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("record {tmp}/rec.mcap --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("monitor --port 0 --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("pose set 1 2 3 --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("ros bridge --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("foxglove --port 0 --timeout 0.5 --connect {nobody}", "{nobody}"),
    ("calibrate mount --court seed-gazebo --camera {tmp}/cam.json --pose 1,2,0 --live --timeout 0.5 "
     "--connect {nobody}", "{nobody}"),
    ("router --listen bogus", "bogus"),
    # bad numbers
    ("shooter rpm -1", "-1"),
    ("shooter rpm abc", "abc"),
    ("shooter rpm nan", "nan"),
    ("pose set 1 2 nan --connect {nobody}", "yaw"),
    ("monitor --port 99999", "--port"),
    ("foxglove --image-hz 0", "--image-hz"),
    ("dataset synth --court seed-gazebo --n 0 --out {tmp}/synth", "--n"),
    ("up --duration 0", "--duration"),
    ("model activate two", "two"),
    ("monitor --rate 100", "--rate"),
    ("replay {five} --speed 0", "--speed"),
    ("localizer crosseval --data {data} --json - --step 0", "--step"),
    ("bench twin --seconds 0", "--seconds"),
    ("bench twin --seconds 0.001 --scenario blackout", "--seconds"),
    ("bench twin --fps nan", "--fps"),
    ("bench twin --infer threads=0 --scenario clean", "infer.threads"),
    ("bench twin --infer bad", "--infer"),
    ("bench fuzz --seconds 0", "--seconds"),
    ("bench fuzz --rate-hz -1", "--rate-hz"),
    ("bench fuzz --fps nan", "--fps"),
    # unknown names
    ("run nosuchstage", "nosuchstage"),
    ("dataset synth --court nosuchcourt --n 2 --out {tmp}/synth", "nosuchcourt"),
    ("record {tmp}/rec.mcap --topics nosuch/topic", "nosuch/topic"),
    ("bench twin --court nosuchcourt --scenario clean", "nosuchcourt"),
    ("bench twin --camera nosuchcamera --scenario clean", "nosuchcamera"),
    ("bench twin --scenario clean,rainy", "rainy"),
    ("bench twin --scenario ,", "--scenario"),
    ("bench twin --fusion maybe", "--fusion"),
    ("bench fuzz --services camera nosuchstage", "nosuchstage"),
    ("calibrate mount --court seed-gazebo --camera nosuchcamera --pose 1,2,0 --frames {tmp}", "nosuchcamera"),
]


# Run as real `python -m courtloc` processes: argparse's own exit, a stage's start, and every mistake that
# opens a zenoh session (the reason the entry point skips interpreter finalization: courtloc.cli.run).
AS_PROCESS = frozenset({
    "nosuchverb",
    "run camera --config {text}",
    "model list --timeout 0.5 --connect {nobody}",
    "record {tmp}/rec.mcap --timeout 0.5 --connect {nobody}",
    "monitor --port 0 --timeout 0.5 --connect {nobody}",
    "router --listen bogus",
    "pose set 1 2 3 --timeout 0.5 --connect {nobody}",
    "ros bridge --timeout 0.5 --connect {nobody}",
    "foxglove --port 0 --timeout 0.5 --connect {nobody}",
    "calibrate mount --court seed-gazebo --camera {tmp}/cam.json --pose 1,2,0 --live --timeout 0.5 "
    "--connect {nobody}",
})


@pytest.fixture(scope="module")
def places(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    from courtloc.training.toy_data import write_toy_dataset

    tmp = tmp_path_factory.mktemp("mistakes")
    five = tmp / "five.mcap"
    five.write_bytes(b"hello")
    cut = tmp / "cut.mcap"  # the MCAP magic, then nothing usable
    cut.write_bytes(b"\x89MCAP0\r\n\x01\x02")
    notonnx = tmp / "model.onnx"
    notonnx.write_text("not a protobuf\n")
    return {"tmp": str(tmp), "data": str(write_toy_dataset(tmp / "toy", frames_per_recording=4)),
            "nobody": endpoint(free_port()), "five": str(five), "cut": str(cut), "notonnx": str(notonnx),
            "text": str(Path(__file__).resolve().parents[1] / "README.md")}


def _courtloc(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([*PYTHON, *argv], capture_output=True, text=True, timeout=60, stdin=subprocess.DEVNULL)


def _answer(done: subprocess.CompletedProcess | Finished) -> tuple[int, str]:
    return done.returncode, done.stderr


def test_every_mistake_is_one_line_and_a_failure(places: dict[str, str], capsys: pytest.CaptureFixture[str],
                                                 caplog: pytest.LogCaptureFixture) -> None:
    assert AS_PROCESS <= {line for line, _ in MISTAKES}
    cases = [(line in AS_PROCESS, line.format(**places).split(), word.format(**places)) for line, word in MISTAKES]
    with ThreadPoolExecutor(max_workers=3) as pool:  # the processes run while the rest run here
        processes = {id(argv): pool.submit(_courtloc, argv) for as_process, argv, _ in cases if as_process}
        answers = {id(argv): _answer(courtloc_in_process(argv, capsys, caplog))
                   for as_process, argv, _ in cases if not as_process}
        for key, future in processes.items():
            answers[key] = _answer(future.result())
    wrong = []
    for _, argv, word in cases:
        code, stderr = answers[id(argv)]
        lines = stderr.strip().splitlines()
        # The line starts with the command it answers ("courtloc bench twin: ..."), as the shared handler says it.
        said_by = "courtloc:" if argv[0] == "nosuchverb" else f"courtloc {argv[0]}"
        if code == 0 or len(lines) != 1 or "Traceback" in stderr or word not in stderr \
                or not stderr.startswith(said_by):
            wrong.append(f"courtloc {' '.join(argv)} -> exit {code}, stderr {stderr!r}")
    assert not wrong, "\n".join(wrong)


def test_json_has_one_meaning_in_every_verb() -> None:
    """Every `--json` takes FILE, `-` standing for standard output (courtloc.cli.EPILOG)."""
    import argparse

    from courtloc.cli import build_parser
    from courtloc.cliargs import json_output, json_to_stdout

    def walk(parser: argparse.ArgumentParser):
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for child in action.choices.values():
                    yield from walk(child)
            elif "--json" in action.option_strings:
                yield parser.prog, action

    found = dict(walk(build_parser()))
    assert {"courtloc bench twin", "courtloc bench fuzz", "courtloc pose set", "courtloc doctor"} <= set(found)
    assert [prog for prog, action in found.items() if action.type is not json_output] == []
    args = build_parser().parse_args(["bench", "twin", "--json", "-"])
    assert json_to_stdout(args.json)
    assert not json_to_stdout(build_parser().parse_args(["bench", "fuzz", "--json", "out.json"]).json)


def test_verbose_shows_the_traceback(places: dict[str, str]) -> None:
    quiet = _courtloc(["secure", "sign", places["text"], "--key", f"{places['tmp']}/missing.key"])
    loud = _courtloc(["-v", "secure", "sign", places["text"], "--key", f"{places['tmp']}/missing.key"])
    assert quiet.returncode == loud.returncode != 0
    assert "Traceback" not in quiet.stderr and "Traceback" in loud.stderr
    assert loud.stderr.strip().splitlines()[-1] == quiet.stderr.strip(), "the same one line ends the traceback"


def test_a_bug_keeps_its_traceback() -> None:
    """Only the known kinds of mistake become one line: anything else is a bug and shows where it is."""
    from courtloc.cli import user_error

    assert user_error(ZeroDivisionError("division by zero")) is None
    assert user_error(FileNotFoundError(2, "No such file or directory", "x.toml")) == (
        "x.toml: No such file or directory", 2)
