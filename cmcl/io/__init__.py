"""Input/output: the msgpack codec, run directories, atomic writes, plots."""
