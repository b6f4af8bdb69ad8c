"""gateway: export a bench's CAN / RS-485 / DI-DO over zenoh, with leases (docs/gateway.md).

Runner side: `hil.gateway.client.acquire(lab, bench, holder=..., connect=[...]) -> Lease`.
Bench side: `hil.gateway.gateway.Gateway(bench, GatewayConfig(...))`, or `hil gateway`.
"""
