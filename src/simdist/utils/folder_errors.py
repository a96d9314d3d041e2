"""Errors about the output folder a run was pointed at: the user's choice, not a bug."""

from __future__ import annotations


class RunFolderError(ValueError):
    """An output folder holds results this run must not use: another config's stages or
    dataset, or a stage record that lacks what this config needs.

    The message names the folder or file and how to proceed. Recipes turn it into an
    ``error:`` line and exit status 2, as for a bad flag
    (:func:`simdist.utils.cli.exit_on_folder_errors`).

    Examples:
        >>> import tempfile
        >>> out = tempfile.mkdtemp()
        >>> from simdist.utils.stages import StageRunner
        >>> StageRunner(out, {"episodes": 8}).close()
        >>> try:
        ...     StageRunner(out, {"episodes": 3})
        ... except RunFolderError as err:
        ...     print(str(err).split(" holds ")[1])
        results of a different config (changed: ['episodes']); use another --output-dir or the same settings
    """


class FolderInUseError(RuntimeError):
    """Another live run holds the output folder's lock; the message names its pid.

    Examples:
        >>> str(FolderInUseError("output folder 'out' is in use by another run"))
        "output folder 'out' is in use by another run"
    """
