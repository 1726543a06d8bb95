"""`threedcal objects export`: the test objects as STL files to 3D-print, with depth previews."""

from __future__ import annotations

import argparse
from pathlib import Path

from threedcal.cli import refuse_existing_outputs, refuse_file_on_path
from threedcal.errors import ConfigError
from threedcal.evaluate.groundtruth import surface_height
from threedcal.evaluate.mesh import write_stl
from threedcal.evaluate.object_figures import plot_depth_preview
from threedcal.evaluate.objects import OBJECT_NAMES, load_object, name_clashes, object_label
from threedcal.profiles import load_profile


def run_objects_export(args: argparse.Namespace) -> int:
    sensor = load_profile("sensor", args.sensor)
    px_per_mm = args.px_per_mm or sensor["px_per_mm"]
    shape = (sensor["image"]["height_px"], sensor["image"]["width_px"])
    if args.indentation_mm <= 0:
        raise ConfigError(f"--indentation-mm must be > 0, got {args.indentation_mm}")
    refs = args.objects or list(OBJECT_NAMES)
    clashes = name_clashes(refs)
    if clashes:  # both would be written to one <name>.stl
        i, first = clashes[0]
        raise ConfigError(
            f"--objects: more than one object is named {object_label(refs[i])!r} "
            f"({refs[first]}, {refs[i]}); rename one file"
        )
    meshes = {object_label(ref): load_object(ref) for ref in refs}  # all checked before writing
    out = Path(args.out)
    refuse_file_on_path("--out", out, out)
    for ref in refs:
        stl = out / f"{object_label(ref)}.stl"
        if stl.is_file() and Path(ref).is_file() and stl.samefile(ref):
            # the export is re-centred: writing it there would replace the user's own file
            raise ConfigError(
                f"--out {out}: {stl} is the --objects file {ref}; export it to another folder"
            )
    names = list(meshes)
    refuse_existing_outputs(
        [("--out", out / f"{n}{end}") for n in names for end in (".stl", "_depth.png")], args.force
    )
    for name, mesh in meshes.items():
        stl = write_stl(mesh, out / f"{name}.stl")
        depth = surface_height(mesh, shape, px_per_mm).depth(args.indentation_mm)
        png = plot_depth_preview(
            depth,
            out / f"{name}_depth.png",
            px_per_mm=px_per_mm,
            title=f"{name}: {args.indentation_mm:g} mm deep, {px_per_mm:g} px/mm",
        )
        size = " x ".join(f"{v:.2f}" for v in mesh.extent)
        print(
            f"{stl}  {size} mm  {len(mesh.faces)} faces  volume {mesh.volume:.1f} mm^3  "
            f"watertight={mesh.is_watertight()}  preview {png.name}"
        )
    return 0
