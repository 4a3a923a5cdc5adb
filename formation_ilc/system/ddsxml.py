"""Fast DDS XML profiles files, edited: a user's profiles file (or none) with settings added to
its default participant profile, written anew for a run's processes.

Fast DDS reads one profiles file (``FASTRTPS_DEFAULT_PROFILES_FILE``), and rmw_fastrtps
takes a participant's settings from its default participant profile. A run that needs
settings of its own (the discovery peers of a large team, a secure run's handshake retries)
builds them on the file the processes would load anyway, keeping everything the user set.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

__all__ = ["PROFILES_NS", "Profiles", "local", "child"]

PROFILES_NS = "http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles"


def local(tag: str) -> str:
    """A tag's name without its namespace."""
    return tag.rsplit("}", 1)[-1]


def child(parent: ET.Element, name: str, ns: str) -> ET.Element:
    """``parent``'s first child called ``name`` (any namespace), made if there is none."""
    for c in parent:
        if local(c.tag) == name:
            return c
    return ET.SubElement(parent, f"{ns}{name}")


class Profiles:
    """A profiles file: ``base``'s (a path) or an empty one. ValueError names a ``base``
    that is not a profiles file."""

    def __init__(self, base: Path | None = None):
        if base is None:
            self.root = ET.Element(f"{{{PROFILES_NS}}}profiles")
        else:
            try:
                self.root = ET.parse(base).getroot()
            except (OSError, ET.ParseError) as exc:
                raise ValueError(f"{base}: not a readable Fast DDS profiles file ({exc})"
                                 ) from None
        profiles = self.root if local(self.root.tag) == "profiles" else next(
            (c for c in self.root if local(c.tag) == "profiles"), None)
        if profiles is None:
            raise ValueError(f"{base}: no <profiles> element (a Fast DDS profiles file?)")
        self.profiles = profiles
        #: the namespace of the file's elements, "{...}" or ""
        self.ns = profiles.tag[:profiles.tag.index("}") + 1] if profiles.tag.startswith(
            "{") else ""

    def default_participant(self, name: str) -> ET.Element:
        """The default participant profile (made, named ``name``, if there is none)."""
        return self.default_profile("participant", name)

    def default_profile(self, kind: str, name: str) -> ET.Element:
        """The default profile of ``kind`` ("participant", "data_writer", "data_reader"):
        the file's, or one made and named ``name``."""
        found = next((c for c in self.profiles if local(c.tag) == kind
                      and c.get("is_default_profile") == "true"), None)
        if found is None:
            found = ET.SubElement(self.profiles, f"{self.ns}{kind}", profile_name=name,
                                  is_default_profile="true")
        return found

    def text(self, comment: str) -> str:
        """The file's text, with ``comment`` after the XML declaration."""
        ET.register_namespace("", self.ns.strip("{}") or PROFILES_NS)
        ET.indent(self.root)
        return ('<?xml version="1.0" encoding="UTF-8"?>\n'
                f"<!-- {comment} -->\n" + ET.tostring(self.root, encoding="unicode") + "\n")
