"""What a scene's test objects may be (a built-in name or a mesh file): checked when the config is
read, so a bad reference stops the study before any collection.

Kept apart from threedcal.evaluate, which builds and reads the objects: the collection's code never
imports the evaluation's, so changing the evaluation never reruns a collection."""

from __future__ import annotations

from pathlib import Path

# The built-in test objects (threedcal.evaluate.objects builds them); any other is a mesh path.
BUILTIN_OBJECTS = ("hemispheres", "pill", "pawn")
# The mesh files a test object may come in (read by trimesh: threedcal.evaluate.mesh).
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".off")


def object_problem(ref: str | Path) -> str | None:
    """What is wrong with a test object reference (a built-in name or a mesh file), or None."""
    text = str(ref)
    if text in BUILTIN_OBJECTS:
        return None
    if Path(text).suffix.lower() not in MESH_SUFFIXES:
        return (
            f"test object {text!r} is neither a built-in ({', '.join(BUILTIN_OBJECTS)}) "
            f"nor a mesh file ({', '.join(MESH_SUFFIXES)})"
        )
    if not Path(text).is_file():
        return f"mesh file {text!r} does not exist"
    return None
