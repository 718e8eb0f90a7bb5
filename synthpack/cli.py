"""The ``synthpack`` command line.

Every subcommand turns a :class:`~synthpack.errors.SynthpackInputError` into one
line on stderr and exit code 2, without a traceback. ``generate`` exits with code
1 when some packs failed (:class:`~synthpack.errors.PackBuildError`), after
building all the others, and with code 2 when every failed pack failed on its
input (:class:`~synthpack.errors.PackInputError`). A Ctrl-C ends any command with
exit code 130 and one line; for ``generate`` it says which packs are complete (a
rerun builds only the missing ones), after removing the staging folders of the
packs it stopped.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import sys
import time
from collections.abc import Sequence
from typing import Any
from pathlib import Path

from . import __version__
from .io.atomic import Output, check_output, remove_stale_staging
from ._shared.console import show_logs
from .store.formats import PACK_FORMATS
from ._shared.schema import build, default_of, help_of, option_name
from .pipeline.config import LibraryConfig, PackConfig, PourConfig
from .library.deform import DeformConfig
from .physics.scene import COLLISION_SHAPES
from .physics.registry import ENGINES, get_engine
from .errors import ContainmentError, PackBuildError, SynthpackInputError
from .io._registry import tomogram_help

logger = logging.getLogger("synthpack")

__all__ = ["main"]

_ENGINE_CHOICES = tuple(ENGINES)


def _number_option(text: str) -> int | float | str:
    """A ``--n-particles``, ``--target-solid-fraction`` or ``--target-coordination`` value: a number as an int or
    a float, a word ('auto', 'source', 'none') as given (all checked by PourConfig)."""
    for kind in (int, float):
        with contextlib.suppress(ValueError):
            return kind(text)
    return text


#: The options of `pour` and `generate` that are `PourConfig` settings (validated by it), with their types.
_POUR_OPTIONS = (("n_particles", _number_option), ("batch_size", int), ("engine", str), ("collision_shape", str),
                 ("tube_radius", float), ("tube_height", float), ("target_solid_fraction", _number_option),
                 ("target_coordination", _number_option))

#: Per command: the options that name an output, and what is written there (``module:Output``),
#: checked before any work starts (:func:`synthpack.io.atomic.check_output`).
_OUTPUTS: dict[str, tuple[tuple[str, str], ...]] = {
    "library build": (("out", "synthpack.library.core:LIBRARY_OUTPUT"), ("preview", "synthpack.preview:PREVIEW_OUTPUT")),
    "generate": (("out", "synthpack.store.pack:PACKS_OUTPUT"),),
    "compare": (("out", "synthpack.realism.report:REPORT_OUTPUT"),),
    "pour": (("out", "synthpack.physics.placements:PLACEMENTS_OUTPUT"),),
    "demo": (("out", "synthpack.cli:DEMO_OUTPUT"),),
    "export-yolo": (("out", "synthpack.export.yolo:YOLO_OUTPUT"),),
    "export-coco": (("out", "synthpack.export.coco:COCO_OUTPUT"),),
    "export-nnunet": (("out", "synthpack.export.nnunet:NNUNET_OUTPUT"),),
    "evaluate": (("out", "synthpack.metrics:EVALUATION_OUTPUT"),),
    "label": (("out", "synthpack.cli:LABELS_OUTPUT"),),
}

#: The demo's folder: an earlier demo (its library) is replaced, anything else is refused.
DEMO_OUTPUT = Output("demo folder", marker="library/library.json")

#: The `label` command's TIFF: never replaced without --overwrite (it may have been corrected by hand since).
LABELS_OUTPUT = Output("label volume", folder=False, never_replaced="it may have been corrected by hand since")

#: The `label` command's options that are `LabelConfig` (validated by it), with their types.
_LABEL_OPTIONS = (("threshold", float), ("contrast", str), ("sigma", float), ("smoothing", float),
                  ("min_distance", int), ("min_voxels", int))


def _check_outputs(command: str, args: argparse.Namespace) -> None:
    """Refuse every output path of `command` that cannot or may not be written, before any work."""
    import importlib

    for option, where in _OUTPUTS.get(command, ()):
        path = getattr(args, option, None)
        if path is not None:
            module, name = where.split(":")
            check_output(path, getattr(importlib.import_module(module), name), overwrite=args.overwrite)


def _add_overwrite_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--overwrite", action="store_true",
                        help="write into an output folder (or replace an output file) that holds something other "
                             "than synthpack's own earlier output; files of other names are kept")


_TOMOGRAM_HELP = tomogram_help()  # the input formats' help terms (synthpack.io._registry)


def _add_voxel_size_arguments(group: argparse._ActionsContainer) -> None:
    group.add_argument("--voxel-size", type=float, nargs="+", metavar="SIZE",
                       help="voxel size: one number, or three in (z, y, x) order; overrides the file metadata")
    group.add_argument("--unit", help="length unit of the voxel size, e.g. um or mm")


def _add_scan_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_argument_group("source scan (give --tomogram and --labels, or --sample)")
    source.add_argument("--tomogram", type=Path, help=_TOMOGRAM_HELP)
    source.add_argument("--labels", type=Path, help="instance labels of the tomogram (0 = background), in any format --tomogram reads")
    source.add_argument("--sample", choices=("large", "small"), help="use a built-in sample scan instead")
    source.add_argument("--sample-seed", type=int, default=0, help="seed of the built-in sample (default 0)")
    _add_voxel_size_arguments(source)


def _read_source_scan(args: argparse.Namespace):
    if args.sample:
        if args.tomogram or args.labels:
            raise SynthpackInputError("give either --sample or --tomogram/--labels, not both")
        if args.voxel_size is not None or args.unit is not None:
            raise SynthpackInputError("--voxel-size and --unit are for --tomogram/--labels: a built-in sample "
                                      "has its own voxel size")
        from .scan.samples import sample_scan

        return sample_scan(args.sample, seed=args.sample_seed)
    if not (args.tomogram and args.labels):
        raise SynthpackInputError(
            "no source scan: give --tomogram T --labels L (or --sample large|small)"
        )
    from .io import read_scan

    voxel_size = None if args.voxel_size is None else tuple(args.voxel_size)
    return read_scan(args.tomogram, args.labels, voxel_size=voxel_size, unit=args.unit)


def _add_library_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("particle extraction and meshing")
    for name, kind in (("density", float), ("min_voxels", int), ("target_faces", int)):
        group.add_argument("--" + name.replace("_", "-"), type=kind, default=default_of(LibraryConfig, name),
                           help=help_of(LibraryConfig, name))
    group.add_argument("--include-border", action="store_true", help=help_of(LibraryConfig, "include_border"))
    group.add_argument("--workers", type=int, default=None, help="meshing processes (default: all cores)")
    group.add_argument("--exclude-test-block", type=int, choices=(0, 1, 2), metavar="AXIS", default=None,
                       help="keep the paper's test slices out of the library: drop particles reaching the "
                            "central 20%% of the slices along AXIS (0, 1 or 2) and measure intensities "
                            "on the other slices")


def _library_options(args: argparse.Namespace, scan) -> dict:
    options = dict(
        min_voxels=args.min_voxels, include_border=args.include_border, density=args.density,
        target_faces=args.target_faces, workers=args.workers,
    )
    if args.exclude_test_block is not None:
        from .scan.split import central_block

        axis = args.exclude_test_block
        options.update(exclude_slices=central_block(scan.shape[axis]), axis=axis)
    return options


def _cmd_library_build(args: argparse.Namespace) -> None:
    scan = _read_source_scan(args)
    logger.debug("read %r", scan)
    from .library.core import ParticleLibrary

    library = ParticleLibrary.from_scan(scan, **_library_options(args, scan))
    library.save(args.out, overwrite=args.overwrite)
    print(library.summary())
    if args.preview:
        from .preview import save_library_preview

        save_library_preview(scan, library, args.preview, overwrite=args.overwrite)
        logger.info("preview written to %s", args.preview)


def _cmd_library_info(args: argparse.Namespace) -> None:
    from .library.core import ParticleLibrary

    print(ParticleLibrary.load(args.library).summary())


def _load_config(args: argparse.Namespace):
    from .pipeline.config import load_config

    config = load_config(args.config)
    pour = _pour_options(args)
    changes = {"pour": pour} if pour else {}
    if args.seed is not None:
        changes["seed"] = args.seed
    if args.deform_strength is not None:
        changes["grains"] = {"deform": dict(vars(config.grains.deform), strength=args.deform_strength)}
    if args.calibrate:
        changes["postprocess"] = "calibrated"
    return config.replace(**changes) if changes else config


def _cmd_generate(args: argparse.Namespace) -> None:
    config = _load_config(args)
    if args.print_config:
        import yaml

        print(yaml.safe_dump(config.to_dict(), sort_keys=False), end="")
        return
    from .pipeline.generate import generate_packs
    from .library.core import ParticleLibrary

    if args.scheduler is None:  # before the library is built; a remote cluster's workers are checked there
        from .render.torch_render import resolve_device

        get_engine(config.pour.engine).check_available()
        resolve_device(config.run.device, config.reconstruct.order)
    if args.library:
        library = ParticleLibrary.load(args.library)
        source = library.source
    else:
        scan = _read_source_scan(args)
        source = scan.source
        library = ParticleLibrary.from_scan(scan, **vars(config.library), progress=not args.quiet)
    try:
        paths = generate_packs(library, args.out, args.n_packs, config, format=args.format, source=source,
                               workers=args.workers, scheduler=args.scheduler, overwrite=args.overwrite,
                               progress=not args.quiet)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(_packs_kept(args.out, args.n_packs)) from None
    if args.preview:
        _write_pack_preview(paths[0], library, paths[0] / "preview.png")
    if not args.quiet:
        print(f"{len(paths)} pack(s) in {args.out}: " + ", ".join(p.name for p in paths))


def _packs_kept(out: Path, n_packs: int) -> str:
    """What an interrupted run leaves in `out`, once the staging folders of its stopped packs are removed."""
    from .pipeline.generate import pack_name
    from .store.pack import is_complete_pack

    complete = []
    for index in range(n_packs):
        path = out / pack_name(index)
        remove_stale_staging(path)  # a pack stopped mid-build, its worker process gone
        if is_complete_pack(path):
            complete.append(path.name)
    if not complete:
        return f"no pack of {n_packs} is complete in {out}; run the same command again to build them"
    if len(complete) == n_packs:
        return f"all {n_packs} packs are complete in {out}"
    names = ", ".join(complete) if len(complete) <= 4 else f"{complete[0]}, {complete[1]}, ..., {complete[-1]}"
    return (f"{len(complete)} of {n_packs} packs are complete in {out} ({names}); run the same command again "
            f"to build only the {n_packs - len(complete)} missing")


def _write_pack_preview(pack_path: Path, library, png: Path) -> Path:
    from .store.pack import open_pack
    from .preview import save_pack_preview

    pack = open_pack(pack_path)
    return save_pack_preview(
        pack.tomogram[:], pack.clean[:], pack.labels[:], pack.voxel_size, pack.unit,
        library.equivalent_diameters, png,
    )


def _auc_summary(classifiers: dict) -> str:
    """``logistic AUC x, cnn AUC y`` of a classifier test's JSON summary."""
    return ", ".join(f"{name} AUC {classifiers[name]['auc']:.3f}" for name in ("logistic", "cnn")
                     if name in classifiers)


def _cmd_compare(args: argparse.Namespace) -> None:
    from .realism import CnnConfig, compare

    if args.source:
        if args.tomogram or args.labels:
            raise SynthpackInputError("give either --source T L or --tomogram/--labels, not both")
        args.tomogram, args.labels = args.source
    slab = {} if args.slab is None else {"slab": args.slab}
    report = compare(_read_source_scan(args), args.packs, patch=args.patch, seed=args.seed,
                     cnn=CnnConfig() if args.cnn else None, ablation=args.ablation, **slab)
    paths = report.write(args.out, overwrite=args.overwrite)
    figures = report.to_dict()
    print(f"floor (source against itself, slabs of {figures['floor']['slab']}): {_auc_summary(figures['floor'])}")
    for pack in figures["packs"]:
        d = pack["distances"]
        print(f"{pack['name']}: {_auc_summary(d['classifier'])}, KS diameter {d['ks_diameter']:.3f}, "
              f"W grains/pores/edges {d['wasserstein_grains']:.3f}/{d['wasserstein_pores']:.3f}/"
              f"{d['wasserstein_edges']:.3f}, edge half height shift {d['edge_half_height_shift']:+.3f}")
        for name, summary in d.get("ablation", {}).items():
            print(f"  {name}: {_auc_summary(summary)}")
    print(f"report: {paths['realism.md']}")


def _cmd_pour(args: argparse.Namespace) -> None:
    from .library.core import ParticleLibrary
    from .physics import pour

    config = build(PourConfig, _pour_options(args), name=option_name)
    placements = pour(ParticleLibrary.load(args.library), config, args.seed, progress=not args.quiet)
    placements.save(args.out, overwrite=args.overwrite)
    checks = placements.checks
    print(f"poured {len(placements)} grains in {len(checks.steps_per_batch)} batches: "
          f"{checks.n_outside} outside the tube, packing fraction {checks.packing_text()}, "
          f"max interpenetration {checks.max_grain_penetration_voxels:.2f} voxels; wrote {args.out}")


def _cmd_demo(args: argparse.Namespace) -> None:
    from .pipeline.config import PackConfig
    from .pipeline.generate import generate_packs
    from .io import write_tiff
    from .library.core import ParticleLibrary
    from .preview import save_library_preview
    from .scan.samples import sample_scan

    out = Path(args.out)
    timings: dict[str, float] = {}
    start = time.perf_counter()
    scan = sample_scan(args.sample, seed=args.seed)
    write_tiff(out / "source" / "tomogram.tif", scan.tomogram, scan.voxel_size, scan.unit)
    write_tiff(out / "source" / "labels.tif", scan.labels, scan.voxel_size, scan.unit, labels=True)
    timings["sample scan"] = time.perf_counter() - start

    start = time.perf_counter()
    library = ParticleLibrary.from_scan(scan)
    library.save(out / "library")
    save_library_preview(scan, library, out / "library_preview.png")
    timings["particle library"] = time.perf_counter() - start

    config = PackConfig().replace(seed=args.seed)
    (path,) = generate_packs(library, out / "packs", 1, config, source=scan.source)
    manifest = json.loads((path / "manifest.json").read_text())
    timings.update(manifest["timings"])

    start = time.perf_counter()
    preview = _write_pack_preview(path, library, out / "pack_preview.png")
    timings["preview"] = time.perf_counter() - start

    print(library.summary())
    print(f"\nsynthetic pack: {path} ({manifest['n_labels']} grains, "
          f"{'x'.join(map(str, manifest['shape']))} voxels, {manifest['contested_voxels']} contested voxels)")
    print(f"pictures: {out / 'library_preview.png'}, {preview}")
    print("seconds per stage: " + ", ".join(f"{k} {v:.1f}" for k, v in timings.items()))


def _source_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments every export takes from the options of `_add_source_arguments`."""
    return {"packs": args.packs or (), "real": [tuple(pair) for pair in args.real or ()], "axis": args.axis,
            "split": args.split, "postprocess": args.postprocess, "overwrite": args.overwrite}


def _slice_options(args: argparse.Namespace) -> dict[str, Any]:
    """The keyword arguments every slice export takes from the options of `_add_export_arguments`."""
    return {**_source_options(args), "val_fraction": args.val_fraction,
            "window": None if args.window is None else tuple(args.window), "min_area": args.min_area}


def _print_export(summary: Any, what: str, path: Path) -> None:
    lo, hi = summary.window
    print(summary.table())
    print(f"\n{what} {path}: {len(summary.sources)} source(s), "
          f"intensity window [{lo:.6g}, {hi:.6g}] ({summary.window_from})")


def _cmd_export_yolo(args: argparse.Namespace) -> None:
    from .export import export_yolo

    summary = export_yolo(args.out, tolerance=args.tolerance, truth_splits=args.truth_splits, **_slice_options(args))
    _print_export(summary, "YOLO dataset", args.out / "data.yaml")


def _cmd_export_coco(args: argparse.Namespace) -> None:
    from .export import export_coco

    summary = export_coco(args.out, **_slice_options(args))
    _print_export(summary, "COCO dataset", args.out / "annotations")


def _cmd_export_nnunet(args: argparse.Namespace) -> None:
    from .export import export_nnunet

    summary = export_nnunet(args.out, **_source_options(args))
    print(summary.table())
    print(f"\nnnU-Net dataset {args.out}: {summary.count('Tr')} training and {summary.count('Ts')} test case(s) "
          f"from {len(summary.sources)} source(s), voxel sizes in {summary.unit}; "
          f"nnUNetv2_plan_and_preprocess -d {summary.dataset_id} --verify_dataset_integrity")


def _cmd_evaluate(args: argparse.Namespace) -> None:
    from .metrics import evaluate_folders

    report = evaluate_folders(args.pred, args.truth, per=args.per, axis=args.axis, iou_threshold=args.iou)
    paths = report.write(args.out, overwrite=args.overwrite)
    print(report.markdown(rows=False), end="")
    print(f"\nreport: {', '.join(str(p) for p in paths.values())}")


def _cmd_label(args: argparse.Namespace) -> None:
    from .io import read_tomogram, write_tiff
    from .scan.labelling import LabelConfig, label_scan

    settings = build(LabelConfig, {name: getattr(args, name) for name, _ in _LABEL_OPTIONS}, name=option_name)
    if args.out.suffix.lower() not in (".tif", ".tiff"):
        raise SynthpackInputError(f"--out {args.out}: the labels are written as a TIFF file; give a name ending in .tif")
    preview = args.out.with_suffix(".png") if args.preview else None
    if preview is not None:
        from .preview import PREVIEW_OUTPUT

        check_output(preview, PREVIEW_OUTPUT, overwrite=args.overwrite)
    voxel_size = None if args.voxel_size is None else tuple(args.voxel_size)
    tomogram, voxel_size, unit = read_tomogram(args.tomogram, voxel_size=voxel_size, unit=args.unit)
    result = label_scan(tomogram, settings)  # logs the starting-point warning, shown under --quiet too
    write_tiff(args.out, result.labels, voxel_size, unit, labels=True)
    summary = f"{result.n_grains} grains labelled in {args.out}"  # how: the INFO line of `label_scan`
    if preview is not None:
        from .preview import save_label_preview

        summary += f", preview {save_label_preview(tomogram, result.labels, preview, overwrite=args.overwrite)}"
    if not args.quiet:
        print(summary)


class _CommandParser(argparse.ArgumentParser):
    """A parser that takes ``-v/--verbose`` and ``-q/--quiet`` (one of them), as do its subcommands' parsers.

    The options are valid before the command and after it (``synthpack -q generate ...`` or
    ``synthpack generate ... -q``); absent, they are left out of the namespace, so that a
    subcommand does not reset what was given before it (`_log_level` reads them).
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        output = self.add_argument_group("output").add_mutually_exclusive_group()
        output.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS,
                            help="also show the details: every measured figure, file written and fitting step")
        output.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                            help="show warnings and errors only, no progress bars (for scripts)")


def _log_level(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """The level of synthpack's log lines that `args` asks for; sets ``args.verbose`` and ``args.quiet``."""
    args.verbose, args.quiet = getattr(args, "verbose", False), getattr(args, "quiet", False)
    if args.verbose and args.quiet:
        parser.error("argument -q/--quiet: not allowed with argument -v/--verbose")
    return logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO


def _parser() -> argparse.ArgumentParser:
    parser = _CommandParser(
        prog="synthpack",
        description="Synthetic CT tomograms of particle packs with exact instance labels.",
    )
    parser.add_argument("--version", action="version", version=f"synthpack {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    _add_demo_command(commands)
    _add_generate_command(commands)
    _add_compare_command(commands)
    _add_pour_command(commands)
    _add_export_command(commands)
    _add_evaluate_command(commands)
    _add_library_command(commands)
    _add_label_command(commands)
    return parser


def _add_demo_command(commands: Any) -> None:
    demo = commands.add_parser("demo", help="run the pipeline on a built-in sample scan")
    demo.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default demo_out)")
    demo.add_argument("--sample", choices=("large", "small"), default="large", help="built-in sample (default large)")
    demo.add_argument("--seed", type=int, default=default_of(PackConfig, "seed"),
                      help=f"seed of the sample scan and the run (default {default_of(PackConfig, 'seed')})")
    _add_overwrite_argument(demo)
    demo.set_defaults(run=_cmd_demo)


def _add_generate_command(commands: Any) -> None:
    generate = commands.add_parser("generate", help="make synthetic packs from a labelled scan or a library")
    _add_scan_arguments(generate)
    generate.add_argument("--library", type=Path, help="use a saved particle library instead of a scan")
    generate.add_argument("--out", type=Path, required=True, help="output folder: one pack_NNNN folder per pack")
    generate.add_argument("--n-packs", type=int, default=1, help="number of packs (default 1)")
    _add_pour_arguments(generate, in_config=True)
    generate.add_argument("--seed", type=int, help="run seed (config seed)")
    generate.add_argument("--deform-strength", type=float, metavar="S",
                          help=help_of(DeformConfig, "strength") + " (config grains.deform.strength)")
    generate.add_argument("--config", type=Path, help="YAML pack config; options above override it")
    generate.add_argument("--format", choices=PACK_FORMATS, default="tiff",
                          help="volume format (default tiff); zarr (also called ome-zarr) writes each pack as "
                               "an OME-Zarr image with its labels (pack.zarr; opens in napari), chunk by "
                               "chunk, for volumes larger than memory")
    where = generate.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="W",
                       help="build the packs on a local Dask cluster of W worker processes (0: in this "
                            "process, one after the other); default: one worker per core, or this process "
                            "for a single pack")
    where.add_argument("--scheduler", metavar="ADDRESS",
                       help="build the packs on an existing Dask cluster, e.g. tcp://10.0.0.5:8786 "
                            "(see the README for SLURM/PBS)")
    generate.add_argument("--preview", action="store_true", help="write preview.png into the first pack")
    generate.add_argument("--print-config", action="store_true", help="print the full config and exit")
    generate.add_argument("--calibrate", action="store_true",
                          help="fit blur and noise to the source scan's edge width and noise level, whatever "
                               "the config says (config postprocess: calibrated, the default)")
    _add_overwrite_argument(generate)
    generate.set_defaults(run=_cmd_generate)


def _add_compare_command(commands: Any) -> None:
    compare = commands.add_parser("compare", help="realism report: how close synthetic packs are to the source scan")
    _add_scan_arguments(compare)
    compare.add_argument("--source", type=Path, nargs=2, metavar=("TOMOGRAM", "LABELS"),
                         help="the source scan (same as --tomogram T --labels L)")
    compare.add_argument("--packs", type=Path, nargs="+", action="extend", default=[], metavar="DIR",
                         help="pack folders, or folders holding pack_NNNN folders (one column per pack); "
                              "without it, the report holds the source and its floor only")
    compare.add_argument("--out", type=Path, required=True,
                         help="report folder: realism.md, realism.json and PNG pictures")
    compare.add_argument("--patch", type=int, default=16, help="classifier patch side in voxels (default 16)")
    compare.add_argument("--seed", type=int, default=default_of(PackConfig, "seed"),
                         help=f"seed of the classifiers' folds and the CNN (default {default_of(PackConfig, 'seed')})")
    compare.add_argument("--slab", type=int, metavar="SLICES",
                         help="the floor's slab thickness along z: the source's even slabs are classified against "
                              "its odd ones (default 10, synthpack.realism.floor.DEFAULT_SLAB)")
    compare.add_argument("--cnn", action=argparse.BooleanOptionalAction, default=True,
                         help="also judge with a small CNN trained from scratch (default: yes)")
    compare.add_argument("--ablation", action=argparse.BooleanOptionalAction, default=True,
                         help="also run the classifiers on each pack's patches with the grains, the pores, all but "
                              "the edges or both phases made flat, to show where the difference lies (default: yes)")
    _add_overwrite_argument(compare)
    compare.set_defaults(run=_cmd_compare)


def _add_pour_arguments(parser: argparse.ArgumentParser, in_config: bool = False) -> None:
    """The options :data:`_POUR_OPTIONS`, unset unless given; `in_config`: their help names the config keys."""
    choices = {"engine": _ENGINE_CHOICES, "collision_shape": COLLISION_SHAPES}
    for name, kind in _POUR_OPTIONS:
        text = help_of(PourConfig, name)
        if in_config:
            key = f"config pour.{name}"
            text = text.replace("(default", f"({key}, default") if "(default" in text else f"{text} ({key})"
        parser.add_argument("--" + name.replace("_", "-"), type=kind, choices=choices.get(name), help=text,
                            metavar="N" if name == "n_particles" else "TARGET" if kind is _number_option else None)


def _pour_options(args: argparse.Namespace) -> dict[str, Any]:
    """The `PourConfig` settings given as options (:data:`_POUR_OPTIONS`), by name."""
    return {name: getattr(args, name) for name, _ in _POUR_OPTIONS if getattr(args, name) is not None}


def _add_pour_command(commands: Any) -> None:
    pour = commands.add_parser("pour", help="pour a library's grains into a tube (placements only)")
    pour.add_argument("--library", type=Path, required=True, help="particle library folder")
    pour.add_argument("--out", type=Path, required=True, help="placements JSON to write")
    _add_pour_arguments(pour)
    pour.add_argument("--seed", type=int, default=default_of(PackConfig, "seed"),
                      help=f"seed (default {default_of(PackConfig, 'seed')}, as generate's)")
    _add_overwrite_argument(pour)
    pour.set_defaults(run=_cmd_pour)


def _add_source_arguments(export: argparse.ArgumentParser, split: str, out: str, axis: str) -> None:
    """The options every export command shares: what is exported, where to, and how it is split.

    `split`: the default split mode; `out`: help of --out; `axis`: what --axis is.
    """
    from .export.slices import SPLIT_MODES

    export.add_argument("--packs", type=Path, nargs="+", action="extend", metavar="DIR",
                        help="pack folders, or folders holding pack_NNNN folders")
    export.add_argument("--real", type=Path, nargs=2, action="append", metavar=("TOMOGRAM", "LABELS"),
                        help="a labelled real scan (repeat for several)")
    export.add_argument("--out", type=Path, required=True, help=out)
    export.add_argument("--axis", type=int, choices=(0, 1, 2), default=0, help=f"{axis} (default 0)")
    export.add_argument("--split", choices=SPLIT_MODES, default=split,
                        help="paper: every volume is split (central 20%% test); real-test: synthetic packs are "
                             f"for training only, whole (default {split})")
    export.add_argument("--postprocess", action=argparse.BooleanOptionalAction, default=True,
                        help="synthetic images from the post-processed tomogram (default) or the clean volume")
    _add_overwrite_argument(export)


def _add_export_arguments(export: argparse.ArgumentParser, pieces: str) -> None:
    """The options every slice export command shares (what is sliced, how, and where to); `pieces`: what --min-area counts."""
    from .export.slices import MIN_AREA, SPLIT_MODES
    from .scan.split import VAL_FRACTION

    _add_source_arguments(export, SPLIT_MODES[0], "dataset folder (new, empty or an earlier export)", "slicing axis")
    export.add_argument("--val-fraction", type=float, default=VAL_FRACTION,
                        help=f"validation slices per volume, next to the test block (default {VAL_FRACTION})")
    export.add_argument("--window", type=float, nargs=2, metavar=("LO", "HI"),
                        help="intensity window for 8 bits (default: 0.5/99.5 percentiles of the real scans, "
                             "else of the first pack's clean volume)")
    export.add_argument("--min-area", type=int, default=MIN_AREA,
                        help=f"{pieces} below this many pixels get no label (default {MIN_AREA})")


def _add_export_command(commands: Any) -> None:
    export = commands.add_parser("export-yolo", help="write packs and real scans as a YOLO segmentation dataset")
    _add_export_arguments(export, "parts (4-connected pieces of an instance's section)")
    export.add_argument("--tolerance", type=float, default=0.0,
                        help="polygon simplification in pixels (default 0: exact outlines)")
    export.add_argument("--truth-splits", nargs="*", choices=("train", "val", "test"), default=["test"],
                        help="splits that also get truth/ instance images for `evaluate` (default test)")
    export.set_defaults(run=_cmd_export_yolo)
    coco = commands.add_parser("export-coco", help="write packs and real scans as a COCO instance-segmentation "
                                                   "dataset (RLE masks)")
    _add_export_arguments(coco, "instances (all pieces of a label in a slice)")
    coco.set_defaults(run=_cmd_export_coco)
    from .export.nnunet import DEFAULT_SPLIT

    nnunet = commands.add_parser("export-nnunet", help="write packs and real scans as an nnU-Net v2 raw dataset "
                                                       "(3D NIfTI; target: background 0, grain 1, boundary 2)")
    _add_source_arguments(nnunet, DEFAULT_SPLIT, "dataset folder named DatasetNNN_Name, e.g. "
                                                 "$nnUNet_raw/Dataset501_Grains (new, empty or an earlier export)",
                          "axis of the central 20%% test block")
    nnunet.set_defaults(run=_cmd_export_nnunet)


def _add_evaluate_command(commands: Any) -> None:
    evaluate = commands.add_parser("evaluate", help="Dice scores of predicted label images against the truth")
    evaluate.add_argument("--pred", type=Path, required=True, help="folder of predicted label images")
    evaluate.add_argument("--truth", type=Path, required=True,
                          help="folder of true label images (.png/.tif/.npy, 2D or 3D, paired by file name)")
    evaluate.add_argument("--out", type=Path, required=True, help="report folder: evaluation.json, .csv, .md")
    evaluate.add_argument("--per", choices=("slice", "volume"), default="slice",
                          help="rows per 2D slice (default) or per 3D file (instances matched in 3D)")
    evaluate.add_argument("--axis", type=int, choices=(0, 1, 2), default=0, help="slicing axis of 3D files (default 0)")
    evaluate.add_argument("--iou", type=float, default=0.5, help="IoU threshold of a matched instance (default 0.5)")
    _add_overwrite_argument(evaluate)
    evaluate.set_defaults(run=_cmd_evaluate)


def _add_label_command(commands: Any) -> None:
    from .scan.labelling import CONTRASTS, LabelConfig

    label = commands.add_parser(
        "label", help="starting instance labels for a scan that has none (threshold + distance-transform "
                      "watershed): a starting point to correct, not ground truth")
    label.add_argument("--tomogram", type=Path, required=True, help=_TOMOGRAM_HELP)
    _add_voxel_size_arguments(label)
    label.add_argument("--out", type=Path, required=True,
                       help="label TIFF to write (0 = pore, 1..N = grains; the scan's voxel size)")
    label.add_argument("--preview", action="store_true",
                       help="also write a PNG of the middle slices with the label outlines, next to --out (.png)")
    group = label.add_argument_group("segmentation (see synthpack.scan.labelling)")
    for name, kind in _LABEL_OPTIONS:
        group.add_argument("--" + name.replace("_", "-"), type=kind, default=default_of(LabelConfig, name),
                           help=help_of(LabelConfig, name), **({"choices": CONTRASTS} if name == "contrast" else {}))
    _add_overwrite_argument(label)
    label.set_defaults(run=_cmd_label)


def _add_library_command(commands: Any) -> None:
    library = commands.add_parser("library", help="build or inspect a particle library")
    library_commands = library.add_subparsers(dest="library_command", required=True, metavar="ACTION")
    build = library_commands.add_parser("build", help="extract and mesh every particle of a labelled scan")
    _add_scan_arguments(build)
    _add_library_arguments(build)
    build.add_argument("--out", type=Path, required=True, help="library folder to write")
    build.add_argument("--preview", type=Path, help="also write a preview PNG here")
    _add_overwrite_argument(build)
    build.set_defaults(run=_cmd_library_build)
    info = library_commands.add_parser("info", help="print a library's particle count and size distribution")
    info.add_argument("library", type=Path, help="library folder")
    info.set_defaults(run=_cmd_library_info)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    with show_logs(_log_level(parser, args)):
        return _run(args)


def _run(args: argparse.Namespace) -> int:
    """Run the command `args` names; returns the exit code."""
    command = " ".join(filter(None, (args.command, getattr(args, "library_command", None))))
    try:
        _check_outputs(command, args)
        args.run(args)
    except SynthpackInputError as error:
        print(f"synthpack: error: {error}", file=sys.stderr)
        return 2
    except (PackBuildError, ContainmentError) as error:
        print(f"synthpack: error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt as interrupt:  # generate says what it kept
        detail = f": {interrupt}" if str(interrupt) else ""
        print(f"synthpack: interrupted{detail}", file=sys.stderr)
        return 130
    except OSError as error:  # disk full, permissions changed mid-run: one line, no traceback
        where = f" ({error.filename})" if error.filename else ""
        print(f"synthpack: error: {error.strerror or error}{where}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
