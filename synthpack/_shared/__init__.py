"""Helpers shared below every stage (private: no stage's public API).

Modules, one job each:

===============  ================================================================================
``arrays``       small array helpers (dtypes, boxes)
``budget``       size, memory and time estimates, checked before any work starts
``chunks``       chunk tiling and the bounded thread map
``console``      log format, ``-v``/``-q``, progress bars, warnings once
``exports``      lazy re-exports for the stage packages' ``__init__``
``plotting``     matplotlib on the headless backend
``schema``       settings dataclasses: defaults, checks, help (`setting`, `build`)
``strict_json``  strict JSON: NaN and inf written as ``null``
``text``         numbers in messages, rounded by meaning
``windows``      intensity windows of figures and exports
===============  ================================================================================
"""
