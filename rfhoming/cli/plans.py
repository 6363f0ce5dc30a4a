"""What ``rfhoming run`` and ``rfhoming node`` make a homing plan of: the device options
(--aoa, --base ..., over the config's [devices.ROLE]) and --tag."""

from __future__ import annotations

import argparse

from rfhoming.host import site as sites
from rfhoming.host.homing.assembly import Device
from rfhoming.host.homing.config import Config
from rfhoming.host.portspec import PortSpec, PortSpecError
from rfhoming.host.portspec import parse as parse_spec
from rfhoming.host.site import Site
from rfhoming.protocol.settings import tags as tag_ids


def tag_option(values: list[str]) -> tuple[str, ...]:
    """--tag values (each one id or ids joined by +) -> upper-case ids; PortSpecError explains."""
    try:
        return tuple(dict.fromkeys(t for v in values for t in tag_ids(v)))
    except ValueError as exc:
        raise PortSpecError(f"--tag takes {exc}") from None


def plan_devices(args: argparse.Namespace, config: Config, role: str) -> tuple[list[Device], Site | None]:
    """The run's devices by role: the command line's specs over the config's [devices.ROLE];
    fixed anchors come from the site file."""
    def spec(r: str, given: str | None = None) -> PortSpec:
        given = given or one_port(getattr(args, r, None))
        found = parse_spec(given).over(config.devices.get(r)) if given else config.devices.get(r)
        if found is None:
            raise PortSpecError(f"--controller {args.controller} needs --{r} PORT (or [devices.{r}] in the config)")
        return found

    site = None
    if role == "anchor":
        if args.site is None:
            raise PortSpecError("--controller anchors needs --site SITE.toml (anchors, and tags with role = "
                                "\"robot\" / \"target\")")
        site = sites.load(args.site)
        site.tag_with_role("robot"), site.tag_with_role("target")
        if any(a.port is None for a in site.anchors):
            raise sites.SiteError(f"{args.site}: every anchor needs port = \"xplr-aoa:WHERE\" for run")
        sensors = [Device("anchor", spec=a.port) for a in site.anchors]
    else:
        given = getattr(args, role, None)
        several = given if isinstance(given, list) and len(given) > 1 else [None]  # --ble, once per receiver
        if several != [None] and args.controller != "survey":
            raise PortSpecError(f"--{role} is given once for --controller {args.controller}; only a survey takes "
                                "one per receiver")
        sensors = [Device(role, spec=spec(role, g)) for g in several]
    return [*sensors, Device("base", spec=spec("base"))], site


def one_port(given: str | list[str] | None) -> str | None:
    """A role's one port from the command line (--ble may be given several times)."""
    return given[0] if isinstance(given, list) else given
