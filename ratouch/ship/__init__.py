"""What ships: `ratouch train all` (every shipped weight retrained in dependency order,
`retrain.py`) and the cascade's calibration over the loaded pipelines (`cascade.py`).

It sits above evaluation and serving (and training), because calibrating the cascade answers
validation renders with the loaded pipelines and reads evaluation's measures; nothing in the
library imports it, only the command line.
"""
