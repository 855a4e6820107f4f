"""jaxnav's version, in a module of its own: the commands read it where the package's
``__init__`` never ran, as when a folder named ``jaxnav`` in the working directory (the folder
holding a clone named jaxnav) is imported as a namespace package in the package's place and
an editable install finds the package's modules beneath it."""

__version__ = "0.1.0"
