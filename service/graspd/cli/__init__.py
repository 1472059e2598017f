"""graspd.cli: the `graspd` command (`main`) and its sub-commands; no algorithm code, it calls the layers."""
