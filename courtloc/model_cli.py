"""`courtloc model ...`: manage the model store of a robot from the pit laptop."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from courtloc.cli_errors import RUN_EXIT, UsageError
from courtloc.cliargs import add_json_argument, json_to_stdout, positive_float, positive_int
from courtloc.common.bus import open_session, wait_for_router
from courtloc.model_client import ModelClient, ModelClientError, push_files
from courtloc.recording.busargs import add_client_arguments, client_deployment

# A pit command asks and expects an answer: it does not wait for a router for ever by default.
ROUTER_TIMEOUT_S = 10.0


def register(sub: argparse._SubParsersAction) -> None:
    model = sub.add_parser("model", help="push, list, activate, roll back or shadow models on a robot")
    common = argparse.ArgumentParser(add_help=False)
    add_client_arguments(common, timeout_s=ROUTER_TIMEOUT_S)
    add_json_argument(common, "the robot's reply")
    ops = model.add_subparsers(dest="model_op", metavar="OP", required=True)

    push = ops.add_parser("push", parents=[common], help="send a model (ONNX file or package folder); resumable")
    push.add_argument("source", type=Path)
    push.add_argument("--no-activate", action="store_true", help="store and validate only")
    push.add_argument("--chunk-mb", type=positive_float, default=4.0)
    push.set_defaults(func=_run, action="push")
    ops.add_parser("list", parents=[common], help="models in the robot's store").set_defaults(func=_run, action="list")
    activate = ops.add_parser("activate", parents=[common], help="serve a stored version")
    activate.add_argument("version", type=positive_int)
    activate.add_argument("--name", default=None)
    activate.set_defaults(func=_run, action="activate")
    ops.add_parser("rollback", parents=[common], help="serve the previously active model").set_defaults(
        func=_run, action="rollback")
    shadow = ops.add_parser("shadow", parents=[common], help="run a version beside the active one ('off' stops)")
    shadow.add_argument("version", help="a version number, 'off', or 'status'")
    shadow.add_argument("--name", default=None)
    shadow.set_defaults(func=_run, action="shadow")


def _run(args: argparse.Namespace) -> int:
    if args.action == "push":
        try:
            push_files(args.source)  # a missing source is said before the bus is joined
        except ModelClientError as exc:
            raise UsageError(str(exc)) from None
    if args.action == "shadow" and args.version not in ("off", "status") and not args.version.isdigit():
        raise UsageError(f"version must be a number, 'off' or 'status', got {args.version!r}")
    config = client_deployment(args)  # a bad file or a missing credential raises, named
    wait_for_router(config.zenoh, args.timeout)
    session = open_session(config.zenoh)
    assert session is not None
    try:
        client = ModelClient(session, config.robot_id)
        if args.action == "push":
            def progress(done: int, total: int) -> None:
                print(f"\rpushed {done / 2**20:8.1f} / {total / 2**20:.1f} MiB", end="", file=sys.stderr)

            reply = client.push(args.source, activate=not args.no_activate,
                                chunk_bytes=int(args.chunk_mb * 2**20), progress=progress)
            print(file=sys.stderr)
        elif args.action == "list":
            reply = client.list()
        elif args.action == "activate":
            reply = client.activate(args.version, args.name)
        elif args.action == "rollback":
            reply = client.rollback()
        else:
            reply = _shadow(client, args)
    except ModelClientError as exc:
        raise UsageError(str(exc), RUN_EXIT) from None
    finally:
        session.close()
    _print_reply(reply, args.json)
    return 0 if reply.ok else 1


def _shadow(client, args: argparse.Namespace):  # noqa: ANN001, ANN202
    if args.version == "off":
        return client.shadow(None, args.name)
    if args.version == "status":
        return client.list()
    return client.shadow(int(args.version), args.name)


def _print_reply(reply, json_out: Path | None) -> None:  # noqa: ANN001
    if json_out is not None:
        json_out.write_text(json.dumps(reply.model_dump(), indent=2))
        if json_to_stdout(json_out):
            return
    if not reply.ok:
        print(f"refused: {reply.reason}")
        return
    if reply.models:
        for m in reply.models:
            flags = " ".join(f for f, on in (("ACTIVE", m.active), ("SHADOW", m.shadow)) if on)
            print(f"{m.name:>16} v{m.version:<4} {m.input_kind:<14} {m.size_bytes / 2**20:8.2f} MiB  {flags}")
    elif reply.version:
        print(f"accepted: {reply.name} v{reply.version} ({reply.reason})")
    else:
        print(f"ok {reply.reason}")
    if reply.shadow is not None and reply.shadow.n:
        s = reply.shadow
        print(f"shadow {s.name} v{s.version}: n={s.n} mean {s.mean_diff_m:.3f} m, p95 {s.p95_diff_m:.3f} m, "
              f"max {s.max_diff_m:.3f} m, yaw {s.yaw_mean_diff_deg:.2f} deg")
