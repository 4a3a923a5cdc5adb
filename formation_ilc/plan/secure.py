"""``launch --secure DIR``: every node of the formation in its SROS2 enclave, Enforce.

The launcher's hook, kept apart from the launcher: :func:`prepare` runs before anything
starts and either refuses (an :class:`OptionError`, one line, exit 2) or returns a
:class:`SecureRun`, whose :meth:`SecureRun.env` turns one process's environment into its
secure one (the same transform for local processes, network-namespace hosts and Pioneer
bridges: ``ip netns exec`` keeps the environment). It refuses when

* the Fast DDS that nodes would load has no DDS-Security (the wheels' build, or a ``pip
  install`` that put it back under the rebuilt rmw, which would run with no security at
  all): the message gives the command that builds the secure one
  (``formation_ilc.system.securedds``);
* the keystore is missing, expired, from another CA, or lacks the enclave of a node that
  would start, or a topic one of them needs (a keystore made for another scenario or
  plant: ``formation_ilc.store.keystore.verify``, against the run's roster);
* robots would share a process (``--container``): one process is one DDS participant, and
  each robot must hold only its own identity.

Each process runs in its roster member's enclave ``<namespace>/<enclave>``
(``formation_ilc.config.roster``: a node's own name, except robot i's fake driver, which
runs in the enclave ``driver_i`` as a real driver would).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from formation_ilc.config.enclaves import Grant, enclave_path
from formation_ilc.core.names import MONITOR_NODE
from formation_ilc.plan.options import OptionError

__all__ = ["SECURITY_ENV", "SecureRun", "prepare"]

#: what rcl reads; every variable a secure run sets
SECURITY_ENV = ("ROS_SECURITY_KEYSTORE", "ROS_SECURITY_ENABLE", "ROS_SECURITY_STRATEGY",
                "ROS_SECURITY_ENCLAVE_OVERRIDE")
#: the launcher's own node (the monitor) runs in the launcher process
LAUNCHER_NODE = MONITOR_NODE


@dataclass(frozen=True)
class SecureRun:
    """A checked keystore for a formation in ``namespace``; ``profile``: where the run's
    Fast DDS profile goes (:meth:`write_profile`: ``base_profile``'s with the handshake
    retries of ``securedds.secure_profile``), None for none."""

    keystore: Path
    namespace: str
    profile: Path | None = None
    base_profile: Path | None = None
    #: whether the loaded rmw applies the profile's handshake settings (the patched build)
    handshake_applies: bool = True

    def variables(self, enclave: str) -> dict[str, str]:
        """The security variables of a process in ``enclave`` (its name in the
        formation's namespace)."""
        out = {"ROS_SECURITY_KEYSTORE": str(self.keystore),
               "ROS_SECURITY_ENABLE": "true",
               "ROS_SECURITY_STRATEGY": "Enforce",
               "ROS_SECURITY_ENCLAVE_OVERRIDE": enclave_path(self.namespace, enclave)}
        if self.profile is not None:
            out["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(self.profile)
        return out

    def write_profile(self) -> None:
        """Write the run's Fast DDS profile (before any process starts)."""
        from formation_ilc.system.securedds import secure_profile

        if self.profile is not None:
            self.profile.write_text(secure_profile(self.base_profile))

    def env(self, base: dict[str, str], enclave: str) -> dict[str, str]:
        """``base`` with the security variables of a process in ``enclave``."""
        return {**base, **self.variables(enclave)}

    def enter_launcher(self) -> None:
        """Put the launcher's own node in its enclave (before rclpy initialises)."""
        os.environ.update(self.variables(LAUNCHER_NODE))


def prepare(keystore: Path | str | None, enclaves: Iterable[str], namespace: str, *,
            container: int = 0, profile: Path | None = None,
            base_profile: Path | None = None, launcher: bool = True,
            grants: Mapping[str, Grant] | None = None) -> SecureRun | None:
    """The secure run for processes in these ``enclaves`` (plus, with ``launcher``, the
    launcher's monitor: not on a host without the leader),
    or None without ``--secure``; OptionError (one line) if it cannot run secure. ``profile``,
    ``base_profile``: :class:`SecureRun`'s (a ``base_profile`` that is no profiles file is
    refused here). ``grants``: what each enclave needs (the run's ``Roster.grants``),
    compared with the keystore's signed permissions before anything starts."""
    if keystore is None:
        return None
    from formation_ilc.store.keystore import KeystoreError, verify
    from formation_ilc.system.securedds import (
        InsecureDds,
        check,
        keeps_profile_properties,
        secure_profile,
    )

    if container:
        raise OptionError("--secure: one process per robot (no --container): a process "
                          "is one DDS participant, and each robot holds only its own "
                          "identity")
    ks = Path(keystore).resolve()
    paths = [enclave_path(namespace, e)
             for e in [*enclaves, *((LAUNCHER_NODE,) if launcher else ())]]
    try:
        verify(ks, paths, grants=grants)
        applies = keeps_profile_properties(check())
        if profile is not None:
            secure_profile(base_profile)
    except (KeystoreError, InsecureDds) as exc:
        raise OptionError(f"--secure: {exc}") from None
    except ValueError as exc:
        raise OptionError(f"--secure: FASTRTPS_DEFAULT_PROFILES_FILE {exc}") from None
    return SecureRun(ks, namespace, profile, base_profile, applies)
