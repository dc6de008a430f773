"""The command lines. The only modules of the library that import the plug-in packages
``baselines`` and ``agents``."""
