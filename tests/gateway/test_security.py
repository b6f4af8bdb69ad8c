"""Secure by default: exposure rules and the CLI's refusal (no network needed)."""

from __future__ import annotations

import argparse

import pytest

from hil.gateway import cli
from hil.gateway.tls import GatewaySecurityError, TlsFiles, acl_section, check_exposure
from hil.transport.zenoh_net import ZenohConfigError, check_endpoint, make_config
from tests.gateway.conftest import bench_yaml


def test_loopback_needs_nothing():
    assert check_exposure(["tcp/127.0.0.1:7447", "tls/localhost:7448"], [],
                          TlsFiles("a", "b", "c")) is False
    assert check_exposure(["tcp/127.0.0.1:7447"], [], None) is False


def test_plain_tcp_off_loopback_is_refused():
    with pytest.raises(GatewaySecurityError, match=r"tcp/0\.0\.0\.0:7447 without TLS"):
        check_exposure(["tcp/0.0.0.0:7447"], [], None)
    with pytest.raises(GatewaySecurityError, match="without TLS"):
        check_exposure(["tcp/192.168.1.5:7447"], [], TlsFiles("a", "b", "c"))
    with pytest.raises(GatewaySecurityError, match="--tls-ca"):
        check_exposure(["tls/192.168.1.5:7447"], [], None)
    assert check_exposure(["tls/192.168.1.5:7447"], [], TlsFiles("a", "b", "c")) is True
    with pytest.raises(GatewaySecurityError, match="only tcp/"):
        check_exposure(["udp/127.0.0.1:7447"], [], None)


def test_acl_denies_by_default_and_allows_named_common_names():
    acl = acl_section(["runner1"])
    assert acl["default_permission"] == "deny"
    assert acl["subjects"] == [{"id": "hil-gateway-peers", "cert_common_names": ["runner1"]}]


def test_tls_endpoint_needs_files(monkeypatch):
    for var in ("HIL_ZENOH_TLS_ROOT_CA", "HIL_ZENOH_TLS_CERT", "HIL_ZENOH_TLS_KEY"):
        monkeypatch.delenv(var, raising=False)
    assert check_endpoint("tls/127.0.0.1:7447") == "tls/127.0.0.1:7447"
    with pytest.raises(ZenohConfigError, match="HIL_ZENOH_TLS_ROOT_CA"):
        make_config("peer", connect=["tls/127.0.0.1:7447"])
    monkeypatch.setenv("HIL_ZENOH_TLS_ROOT_CA", "/x/ca.pem")
    monkeypatch.setenv("HIL_ZENOH_TLS_CERT", "/x/c.pem")
    with pytest.raises(ZenohConfigError, match="set together"):
        make_config("peer", connect=["tls/127.0.0.1:7447"])


def _args(tmp_path, *extra: str) -> argparse.Namespace:
    bench = tmp_path / "b.yaml"
    bench.write_text(bench_yaml("b1", "virtual:x", None))
    p = argparse.ArgumentParser()
    cli.configure(p)
    return p.parse_args(["--bench", str(bench), "--no-record", *extra])


def test_cli_refuses_network_listen_without_tls(tmp_path, capsys):
    assert cli.main(_args(tmp_path, "--listen", "tcp/0.0.0.0:7447")) == 2
    err = capsys.readouterr().err
    assert "refusing to expose the bench on tcp/0.0.0.0:7447 without TLS" in err
    assert cli.main(_args(tmp_path, "--tls-ca", "x.pem")) == 2
    assert "all of --tls-ca, --tls-cert and --tls-key" in capsys.readouterr().err


def test_cli_defaults_to_loopback(tmp_path):
    gw = cli.build(_args(tmp_path))
    assert gw.config.listen == ["tcp/127.0.0.1:7447"] and gw.config.mode == "peer"
    assert gw.prefix == "lab/b1"
    gw2 = cli.build(_args(tmp_path, "--connect", "tcp/127.0.0.1:7000", "--lab", "l2"))
    assert gw2.config.listen == [] and gw2.config.mode == "client" and gw2.prefix == "l2/b1"
