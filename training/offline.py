"""Run Ultralytics fully offline, with every file it writes inside one run folder.

Ultralytics downloads nothing when a model is built from its ``.yaml`` with
``pretrained=False`` and ``amp=False`` (its AMP check loads downloaded weights),
``YOLO_OFFLINE=1`` is set (its online checks answer "offline" at once), and the
font it draws labels with is already in its config folder. `offline_ultralytics`
sets all of that up before Ultralytics is first imported and returns the
``YOLO`` class. Call it before anything imports ``ultralytics``.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
from pathlib import Path

logger = logging.getLogger(__name__)

#: Keyword arguments of ``YOLO.train`` that keep training offline and quiet.
OFFLINE_TRAIN_ARGS = {"pretrained": False, "amp": False, "plots": False}


def _font_file() -> Path:
    """matplotlib's DejaVuSans.ttf, a free font that stands in for Ultralytics' Arial.ttf."""
    import matplotlib

    return Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"


def offline_ultralytics(config_dir: str | os.PathLike):
    """Point Ultralytics at `config_dir`, switch it offline and return its ``YOLO`` class.

    Parameters
    ----------
    config_dir : path-like
        Folder for Ultralytics' settings (``Ultralytics/settings.json``) and font
        (``Ultralytics/Arial.ttf``, a copy of matplotlib's DejaVuSans); created if needed.

    Returns
    -------
    type
        ``ultralytics.YOLO``.

    Raises
    ------
    RuntimeError
        If Ultralytics was imported before with another config folder: its
        settings are read once per process.
    """
    config_dir = Path(config_dir).resolve()
    font = config_dir / "Ultralytics" / "Arial.ttf"
    font.parent.mkdir(parents=True, exist_ok=True)
    if not font.exists():
        shutil.copyfile(_font_file(), font)
    previous = os.environ.get("YOLO_CONFIG_DIR")
    if "ultralytics" in sys.modules and previous != str(config_dir):
        raise RuntimeError(
            f"ultralytics was imported before offline_ultralytics({config_dir}) (config folder {previous}): "
            "call offline_ultralytics first, in a fresh process"
        )
    os.environ["YOLO_CONFIG_DIR"] = str(config_dir)
    os.environ["YOLO_OFFLINE"] = "1"
    os.environ.setdefault("YOLO_VERBOSE", "False")
    from ultralytics import YOLO, settings

    settings.update({"sync": False, "clearml": False, "comet": False, "dvc": False, "mlflow": False,
                     "raytune": False, "tensorboard": False, "wandb": False, "vscode_msg": False,
                     "openvino_msg": False, "runs_dir": str(config_dir / "runs"), "weights_dir": str(config_dir / "weights"),
                     "datasets_dir": str(config_dir / "datasets")})
    logger.info("ultralytics offline, settings in %s", config_dir / "Ultralytics")
    return YOLO
