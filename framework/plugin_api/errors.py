"""mmcsplat's user-facing errors: every one derives from :class:`MmcsplatError`, whose message (its one
argument, so that a step can name what it was making in it) the CLI prints on one line before exiting with
status 2. A leaf module."""


class MmcsplatError(Exception):
    """An error whose message tells the user what is wrong and where (file, camera, frame, plugin)."""


class PluginError(MmcsplatError):
    """Base class of every registry error; the message names the plugin and its distribution."""


class UnknownPluginError(PluginError, KeyError):
    """No plugin of that kind is registered under that name."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class DuplicatePluginError(PluginError):
    """A name registered by more than one distribution."""


class BrokenPluginError(PluginError):
    """A plugin whose factory failed to import."""


class PluginUnavailableError(PluginError):
    """A plugin that cannot run here (a missing optional dependency, no CUDA device)."""


class InputError(MmcsplatError, ValueError):
    """A file, setting or piece of data that cannot be used as given (a ``ValueError`` too)."""


class SubjectMaskError(InputError):
    """Subject masks that cannot place the subject: empty in every view a fit trains on, or with no point
    inside all of them. Raised where the masks themselves are at fault, so that a caller that made them
    (``mmcsplat run``'s segmenters) can say how to make better ones."""


class MissingFileError(MmcsplatError, FileNotFoundError):
    """A file or folder that should be there and is not (a ``FileNotFoundError`` too)."""


class OutputExistsError(MmcsplatError, FileExistsError):
    """An output that exists already and may not be replaced without being asked (a ``FileExistsError`` too)."""


class NotAFolderError(MmcsplatError, NotADirectoryError):
    """A path that should be a folder and is a file (a ``NotADirectoryError`` too)."""
