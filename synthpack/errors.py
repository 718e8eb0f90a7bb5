"""Exception types raised by synthpack: bad input, and packs that failed to build."""

from __future__ import annotations

from collections.abc import Mapping


class SynthpackInputError(ValueError):
    """Input that synthpack cannot use: the message says what is wrong and what to do.

    Raised for a missing or unreadable file, volumes of mismatched shape, a label
    volume that is not integral, an invalid configuration value, a corrupt cache and
    similar problems in what the user handed in. The command-line interface turns it
    into a one-line message on stderr and exit code 2, without a traceback.
    """


class PackBuildError(RuntimeError):
    """Some packs of a run failed; every other pack was built and written.

    Packs are written atomically, so a failed pack leaves nothing behind and
    running the same command again builds only the missing packs.

    Attributes
    ----------
    failures : dict of str to str
        Name of each failed pack (``pack_0003``) -> its error, ``"ExceptionType: message"``.
    out : Path
        The run's output directory.
    n_packs : int
        Packs in the run.
    """

    def __init__(self, failures: Mapping[str, str], out, n_packs: int) -> None:
        self.failures = dict(sorted(failures.items()))
        self.out = out
        self.n_packs = n_packs
        listed = "; ".join(f"{name}: {error}" for name, error in self.failures.items())
        super().__init__(
            f"{len(self.failures)} of {n_packs} packs failed ({listed}); the others are in {out}. "
            "Fix the cause and run the same command again: only the missing packs are built"
        )

    @staticmethod
    def of(errors: Mapping[str, BaseException], out, n_packs: int) -> PackBuildError:
        """The error of a run whose packs `errors` (name -> exception) failed.

        A `PackInputError` when every one failed on its input (a
        `SynthpackInputError`), else a `PackBuildError`.
        """
        kind = PackInputError if all(isinstance(e, SynthpackInputError) for e in errors.values()) else PackBuildError
        return kind({name: f"{type(error).__name__}: {error}" for name, error in errors.items()}, out, n_packs)


class PackInputError(PackBuildError, SynthpackInputError):
    """Packs of a run failed, every one on its input: a `PackBuildError` that is also a `SynthpackInputError`.

    The command-line interface reports it as input errors are: one line on
    stderr, exit code 2.
    """


class ContainmentError(RuntimeError):
    """A pour left grains outside its tube or above its rim, so no pack is made of it.

    Raised by :func:`synthpack.physics.pour` after its retry (see there); the message
    says how many grains and what to change. The command-line interface prints it as
    one line and exits with 1.
    """
