"""`hil gateway --bench FILE`: export a bench's buses over zenoh (docs/gateway.md).

Prints `hil gateway: ready: ...` once every bus is exported (or reports the ones still down),
stops on SIGINT/SIGTERM (a held lease ends with the safe state).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from hil.bench.bench import PlanFileError, load_bench
from hil.gateway.gateway import Gateway, GatewayConfig
from hil.gateway.tls import GatewaySecurityError, TlsFiles

DEFAULT_LISTEN = "tcp/127.0.0.1:7447"


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--bench", type=Path, required=True, metavar="FILE",
                   help="bench file (docs/benches.md): the buses to export")
    p.add_argument("--lab", default="lab", help="lab name, first key chunk (default: lab)")
    p.add_argument("--name", metavar="BENCH", help="bench name in keys (default: the file's name)")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help=f"zenoh endpoint to listen on (repeatable; default {DEFAULT_LISTEN} "
                        "unless --connect is given). Off loopback only tls/ with TLS files")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="zenoh endpoint to connect to, e.g. a router (repeatable)")
    p.add_argument("--mode", choices=("peer", "client"),
                   help="zenoh mode (default: client with --connect only, else peer)")
    p.add_argument("--tls-ca", type=Path, metavar="PEM", help="root CA that signs every peer")
    p.add_argument("--tls-cert", type=Path, metavar="PEM", help="this gateway's certificate")
    p.add_argument("--tls-key", type=Path, metavar="PEM", help="this gateway's private key")
    p.add_argument("--allow-cn", action="append", default=[], metavar="CN",
                   help="only peers whose certificate common name is CN get anything "
                        "(repeatable; zenoh access control)")
    p.add_argument("--lease-timeout", type=float, default=3.0, metavar="S",
                   help="a lease without keep-alive ends after S seconds (default 3)")
    p.add_argument("--health-period", type=float, default=1.0, metavar="S",
                   help="publish health every S seconds (default 1)")
    p.add_argument("--record", type=Path, metavar="FILE.mcap",
                   help="the gateway's own recording (default: reports/gateway/<lab>-<bench>-"
                        "<time>.mcap)")
    p.add_argument("--no-record", action="store_true", help="do not record")
    p.add_argument("--no-safe-on-release", action="store_true",
                   help="do not drive the safe state when a holder releases its lease "
                        "(an expired lease always does)")


def build(args: argparse.Namespace):
    """The Gateway an argument set stands for (not started); raises ValueError on bad input."""
    bench = load_bench(args.bench)
    tls_args = (args.tls_ca, args.tls_cert, args.tls_key)
    if any(tls_args) and not all(tls_args):
        raise GatewaySecurityError("TLS needs all of --tls-ca, --tls-cert and --tls-key")
    tls = TlsFiles(*tls_args) if all(tls_args) else None
    listen = list(args.listen) or ([] if args.connect else [DEFAULT_LISTEN])
    mode = args.mode or ("client" if args.connect and not args.listen else "peer")
    record = None
    if not args.no_record:
        name = args.name or bench.name
        record = args.record or Path("reports", "gateway",
                                     f"{args.lab}-{name}-{time.strftime('%Y%m%d-%H%M%S')}.mcap")
    config = GatewayConfig(lab=args.lab, bench=args.name, listen=listen,
                           connect=list(args.connect), mode=mode, tls=tls,
                           allow_cn=list(args.allow_cn), lease_timeout_s=args.lease_timeout,
                           health_period_s=args.health_period, record=record,
                           safe_on_release=not args.no_safe_on_release)
    return Gateway(bench, config)


def main(args: argparse.Namespace) -> int:
    try:
        gw = build(args)
    except (ValueError, PlanFileError, OSError) as e:
        print(f"hil gateway: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        gw.start()
    except Exception as e:  # zenoh / endpoint errors name the endpoint
        print(f"hil gateway: {e}", file=sys.stderr)
        return 1
    try:
        up = gw.wait_ready(10.0)
        down = [f"{e.kind} {e.name} ({e.health.last_error})" for e in gw.exports()
                if e.health.link != "up"]
        note = "" if up else f" (still down, retrying: {'; '.join(down)})"
        rec = f"; recording {gw.config.record}" if gw.config.record else ""
        print(f"hil gateway: ready: {gw.describe()}{note}{rec}", flush=True)
        while not stop.wait(0.2):
            pass
    finally:
        gw.stop()
        print("hil gateway: stopped", flush=True)
    return 0
