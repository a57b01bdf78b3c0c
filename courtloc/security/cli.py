"""`courtloc secure ...`: make a team's credentials, print the router's access rules, sign models."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from courtloc.common.signing import ModelSignatureError, sign_model, signature_path, verify_model
from courtloc.security.acl import access_control
from courtloc.security.bundle import init_bundles


def register(sub: argparse._SubParsersAction) -> None:
    secure = sub.add_parser("secure", help="credentials, access rules and model signatures")
    actions = secure.add_subparsers(dest="secure_action", metavar="ACTION")

    init = actions.add_parser("init", help="create a CA, certificates, passwords and the model-signing key")
    init.add_argument("--out", type=Path, required=True, help="a new (or empty) folder")
    init.add_argument("--robot", default="robot1", help="robot id (one key chunk of the bus)")
    init.add_argument("--hostname", action="append", default=[],
                      help="a name or address the pit uses to reach the robot's router (repeatable); "
                           "default: <robot>.local")
    init.add_argument("--team", default="courtloc team", help="organisation name in the certificates")
    init.add_argument("--pit-stages", nargs="*", default=[],
                      help="stages that run on the laptop (offload: infer): their identities go to pit/ too")
    init.set_defaults(func=run_init)

    acl = actions.add_parser("acl", help="print the router's access-control list for a robot (JSON)")
    acl.add_argument("--robot", default="robot1")
    acl.set_defaults(func=run_acl)

    sign = actions.add_parser("sign", help="sign a model file with the pit's ed25519 key (writes MODEL.sig)")
    sign.add_argument("model", type=Path)
    sign.add_argument("--key", type=Path, required=True, help="pit/model_signing.key")
    sign.set_defaults(func=run_sign)

    verify = actions.add_parser("verify", help="check a model against its signature and the public key")
    verify.add_argument("model", type=Path)
    verify.add_argument("--key", type=Path, required=True, help="robot/model_signing.pub")
    verify.add_argument("--signature", type=Path, default=None, help="default: MODEL.sig")
    verify.set_defaults(func=run_verify)


def run_init(args: argparse.Namespace) -> int:
    hostnames = args.hostname or [f"{args.robot}.local"]
    bundles = init_bundles(args.out, args.robot, hostnames, args.team, args.pit_stages)  # mistakes: one line
    print(f"robot bundle: {bundles.robot.root}  (copy to the robot; set [router] secure_dir and "
          f"[zenoh.security] dir to it)")
    print(f"pit bundle:   {bundles.pit.root}  (stays on the laptop; identity = \"pit\")")
    print(f"CA key:       {bundles.ca_dir / 'ca.key'}  (keep offline)")
    print(f"router certificate names: {', '.join(hostnames)} + loopback")
    return 0


def run_acl(args: argparse.Namespace) -> int:
    print(json.dumps(access_control(args.robot), indent=2))
    return 0


def run_sign(args: argparse.Namespace) -> int:
    print(sign_model(args.model, args.key))
    return 0


def run_verify(args: argparse.Namespace) -> int:
    try:
        digest = verify_model(args.model, args.signature or signature_path(args.model), args.key)
    except (ModelSignatureError, OSError) as exc:
        print(f"REFUSED {args.model}: {exc}", file=sys.stderr)
        return 1
    print(f"OK {args.model} sha256={digest}")
    return 0
