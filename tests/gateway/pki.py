"""Test PKI with openssl (the `cryptography` package is not installed): a CA, another CA,
and leaf certificates valid for localhost and 127.0.0.1 (rustls checks the SAN against the
endpoint's host), usable for server and client auth."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

EXT = ("subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
       "keyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n")


def have_openssl() -> bool:
    return shutil.which("openssl") is not None


def _run(*args: str) -> None:
    subprocess.run(["openssl", *args], check=True, capture_output=True, timeout=30)


def make_ca(d: Path, name: str) -> Path:
    _run("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
         "-nodes", "-days", "2", "-subj", f"/CN={name}", "-keyout", str(d / f"{name}.key"),
         "-out", str(d / f"{name}.pem"))
    return d / f"{name}.pem"


def make_leaf(d: Path, name: str, ca: str, cn: str) -> tuple[Path, Path]:
    key, csr, pem, ext = (d / f"{name}.{x}" for x in ("key", "csr", "pem", "ext"))
    _run("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
         "-subj", f"/CN={cn}", "-keyout", str(key), "-out", str(csr))
    ext.write_text(EXT)
    _run("x509", "-req", "-in", str(csr), "-CA", str(d / f"{ca}.pem"), "-CAkey",
         str(d / f"{ca}.key"), "-CAcreateserial", "-days", "2", "-extfile", str(ext),
         "-out", str(pem))
    return pem, key


def make_pki(d: Path) -> dict[str, Path]:
    make_ca(d, "ca")
    make_ca(d, "otherca")
    out = {"ca": d / "ca.pem"}
    for name, ca, cn in (("gateway", "ca", "gateway"), ("runner", "ca", "runner1"),
                         ("intruder", "otherca", "runner1"), ("stranger", "ca", "stranger")):
        out[f"{name}.pem"], out[f"{name}.key"] = make_leaf(d, name, ca, cn)
    return out
