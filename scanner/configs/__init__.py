"""Configuration files: the example configurations (`*.yaml` here, each loaded by a test) and
the one loader every configuration record goes through (`typed_yaml`: YAML <-> frozen
dataclasses, unknown keys and wrong types refused with the key path)."""
