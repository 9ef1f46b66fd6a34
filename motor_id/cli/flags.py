"""The command line's names for the library's parameters.

The library names a setting by its parameter (``R_m``, ``init_samples``, a mapping's
``speed``) and lists them in a :class:`motor_id.errors.MotorIdError`'s ``params``; the
one-line error of ``motor-id`` adds the flags that set them (:func:`flag_hint`).
"""

from collections.abc import Iterable
import re

FLAGS = {
    'R_m': '-R/--resistance',
    'R_m_tolerance': '--resistance-tolerance',
    'fixed': '--fix',
    'out_dir': '--out',
}
"""The flags whose name is not the parameter's with dashes for underscores."""


def flag(param: str) -> str:
    """The flag that sets ``param`` (``init_samples`` -> ``--init-samples``)."""
    return FLAGS.get(param, '--' + param.replace('_', '-'))


def flag_hint(params: Iterable[str], help_text: str | None = None) -> str:
    """`` (command line: --a, --b)`` for the parameters an error names, or ``''``.

    Parameters
    ----------
    params : iterable of str
        The error's ``params``.
    help_text : str, optional
        The subcommand's ``--help`` text: only the flags it has are named (``motor-id
        fleet`` maps a topic with a profile key, not with ``--speed``).
    """
    flags = [f for f in dict.fromkeys(flag(p) for p in params)
             if help_text is None or re.search(rf'(?<![\w-]){re.escape(f.split("/")[-1])}'
                                               r'(?![\w-])', help_text)]
    return f' (command line: {", ".join(flags)})' if flags else ''
