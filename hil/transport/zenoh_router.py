"""The project's zenoh router: `python -m hil.transport.zenoh_router --listen tcp/127.0.0.1:PORT`.

Prints `ready <endpoint>` once listening; stops on SIGINT/SIGTERM, and with
`--exit-on-stdin-eof` also when its stdin closes (its parent died). Buses attached to it
use mode=client (docs/dev/feasibility.md §2.4 gotcha 3).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

from hil.transport.zenoh_net import close_session, make_config, open_session


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m hil.transport.zenoh_router")
    ap.add_argument("--listen", action="append", required=True,
                    help="endpoint, e.g. tcp/127.0.0.1:7447 (repeatable)")
    ap.add_argument("--exit-on-stdin-eof", action="store_true")
    ap.add_argument("--allow-remote", action="store_true")
    args = ap.parse_args(argv)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        session = open_session(make_config("router", listen=args.listen,
                                           allow_remote=args.allow_remote), what="router")
    except (ValueError, ConnectionError) as e:
        print(f"error: {e}", flush=True)
        return 2
    if args.exit_on_stdin_eof:
        def _watch() -> None:
            sys.stdin.read()  # returns at EOF
            stop.set()

        threading.Thread(target=_watch, daemon=True, name="stdin-eof").start()
    print(f"ready {' '.join(args.listen)}", flush=True)
    try:
        while not stop.wait(0.2):
            pass
    finally:
        close_session(session)
    return 0


if __name__ == "__main__":
    sys.exit(main())
