"""A lab's board frame description from its YAML file, every problem located (file:line:column).

The description's data model, validation and codec are in the drivers layer
(:mod:`drivers.board_frames`, which knows nothing of bench); this module reads the file with
:mod:`bench.yamlsrc` and turns each problem's key path into the place it was written. The format:
docs/frame-descriptions.md.
"""

from __future__ import annotations

from pathlib import Path

from bench.errors import InputError, InputErrors, Location
from bench.yamlsrc import Node, Source, load_yaml
from drivers.board_frames import FrameDescription, FrameDescriptionError, path_text
from drivers.frame_schema import description_from_mapping


def load_frame_description(path: str | Path) -> FrameDescription:
    """The frame description in ``path``; :class:`InputErrors` listing every problem at its line."""
    return frame_description_from_source(load_yaml(path, "frame description"))


def frame_description_from_source(src: Source) -> FrameDescription:
    """The frame description of a loaded YAML document (its text kept in ``.text`` for run files)."""
    try:
        return description_from_mapping(src.root.plain(), str(src.path), src.text)
    except FrameDescriptionError as exc:
        raise InputErrors([InputError(message, locate(src.root, p), path_text(p)) for p, message in exc.problems]) from None


def locate(root: Node, path: tuple) -> Location:
    """Where the value at key path ``path`` is written (or, for a missing one, its mapping)."""
    node, loc = root, root.location
    for key in path:
        if isinstance(node.value, dict) and key in node.value:
            loc = node.key_locations.get(key, node.value[key].location)
            node = node.value[key]
        elif isinstance(node.value, list) and isinstance(key, int) and 0 <= key < len(node.value):
            node = node.value[key]
            loc = node.location
        else:
            break
    return loc
