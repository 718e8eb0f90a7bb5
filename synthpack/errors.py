"""Exception types raised by synthpack for bad input."""


class SynthpackInputError(ValueError):
    """Input that synthpack cannot use: the message says what is wrong and what to do.

    Raised for a missing or unreadable file, volumes of mismatched shape, a label
    volume that is not integral, an invalid configuration value, a corrupt cache and
    similar problems in what the user handed in. The command-line interface turns it
    into a one-line message on stderr and exit code 2, without a traceback.
    """
