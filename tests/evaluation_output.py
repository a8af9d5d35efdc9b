"""What `python -m cmcl evaluate RUN_DIR` prints, read back: one JSON object, then the text lines about the misses,
the GIF and the learning curve."""

import json


def evaluation_json(stdout: str) -> dict:
    """The JSON object at the head of an evaluation's standard output (everything up to its last closing brace)."""
    return json.loads(stdout[:stdout.rindex("}") + 1])
