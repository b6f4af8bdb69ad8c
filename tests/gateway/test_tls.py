"""Mutual TLS on 127.0.0.1 with certificates made by the test: the right runner gets in; no
certificate, a certificate from another CA, or an unlisted common name get nothing."""

from __future__ import annotations

import json
import time

import pytest

from hil.gateway.client import acquire
from hil.gateway.tls import TlsFiles
from hil.transport.can_bus import open_can
from hil.transport.zenoh_net import close_session, make_config, open_session
from tests.gateway.conftest import sdo_read_statusword
from tests.gateway.pki import have_openssl, make_pki

pytestmark = pytest.mark.skipif(not have_openssl(),
                                reason="needs openssl to make test certificates "
                                       "(the cryptography package is not installed)")


@pytest.fixture
def tls_rig(make_rig, tmp_path, free_port_factory):
    pki = make_pki(tmp_path)
    port = free_port_factory()
    files = TlsFiles(pki["ca"], pki["gateway.pem"], pki["gateway.key"])
    rig = make_rig("bench1", listen=[f"tls/127.0.0.1:{port}"],
                   config={"tls": files, "allow_cn": ["runner1"]})
    return rig, pki, f"tls/127.0.0.1:{port}"


def use(monkeypatch, pki, who: str | None) -> None:
    monkeypatch.setenv("HIL_ZENOH_TLS_ROOT_CA", str(pki["ca"]))
    if who is None:
        monkeypatch.delenv("HIL_ZENOH_TLS_CERT", raising=False)
        monkeypatch.delenv("HIL_ZENOH_TLS_KEY", raising=False)
    else:
        monkeypatch.setenv("HIL_ZENOH_TLS_CERT", str(pki[f"{who}.pem"]))
        monkeypatch.setenv("HIL_ZENOH_TLS_KEY", str(pki[f"{who}.key"]))


def test_right_client_gets_in(tls_rig, monkeypatch):
    _rig, pki, ep = tls_rig
    use(monkeypatch, pki, "runner")
    with acquire("lab", "bench1", holder="tls-runner", connect=[ep]) as lease:
        assert lease.can_url("can0").endswith(f"connect={ep}&mode=peer")
        bus = open_can(lease.can_url("can0"))  # TLS files from the environment
        try:
            assert sdo_read_statusword(bus).arbitration_id == 0x581
        finally:
            bus.shutdown()


@pytest.mark.parametrize("who", [None, "intruder"], ids=["no-certificate", "other-ca"])
def test_unauthenticated_client_cannot_connect(tls_rig, monkeypatch, who):
    rig, pki, ep = tls_rig
    use(monkeypatch, pki, who)
    with pytest.raises(ConnectionError, match="no zenoh peer or router reachable"):
        acquire("lab", "bench1", holder="x", connect=[ep], timeout_s=1.0)
    assert rig.gateway.lease.current is None


def test_unlisted_common_name_gets_nothing(tls_rig, monkeypatch):
    rig, pki, ep = tls_rig
    use(monkeypatch, pki, "stranger")  # signed by the right CA, CN not in --allow-cn
    with pytest.raises(ConnectionError, match="no gateway answered"):
        acquire("lab", "bench1", holder="stranger", connect=[ep], timeout_s=1.0)
    s = open_session(make_config("peer", connect=[ep]))
    try:
        got: list = []
        sub = s.declare_subscriber("lab/**", lambda smp: got.append(smp))
        time.sleep(0.6)  # > 2 health periods of the rig
        sub.undeclare()
        assert got == []
        assert [r for r in s.get("lab/bench1/health", timeout=0.5) if r.ok] == []
    finally:
        close_session(s)
    assert rig.gateway.lease.current is None
    # while the listed runner still sees the health reports
    use(monkeypatch, pki, "runner")
    s = open_session(make_config("peer", connect=[ep]))
    try:
        replies: list = []
        deadline = time.monotonic() + 5.0  # a get before the TLS session is up gets nothing
        while not replies and time.monotonic() < deadline:
            replies = [json.loads(r.ok.payload.to_bytes())
                       for r in s.get("lab/bench1/health", timeout=1) if r.ok]
        assert replies and replies[0]["buses"]["can/can0"]["link"] == "up"
    finally:
        close_session(s)
