"""The planning layer of ``formation-ilc launch``, below the command line: the run's typed
options (``options.LaunchOptions``, every default in one place) and the keys of a run file
that hold them. Nothing here parses a command line or needs ROS."""
