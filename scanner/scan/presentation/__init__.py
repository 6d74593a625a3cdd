"""Presentation: how the object is offered to the cameras and turned between passes, one
module per kind, each behind the same small interface (`base.Presentation`).

- hanging: the object hangs from the rod; a person re-hangs it between passes, told how in
  words and a picture (the simulated operator follows with a person's error).
- turntable: the object stands on a motorised turntable; the scanner turns it by angles it
  chooses from what the passes so far have seen, and the known turn starts the alignment.
- table: the object lies on the support table; a person lays it on another face between
  passes, the stable face that shows most of what is unseen, told in words and a picture.

The cell model holds what carries the object (robots/models: the rod, the turntable's disc
and post, or the table); `presentation:` in the configuration (`--presentation`) picks the kind.
"""

from __future__ import annotations

from robots.models.workcell import check_presentation
from scanner.configs.scan import PRESENTATIONS  # noqa: F401  (the names, validated there)


def presentation_for(config, store):
    """The configured presentation (`config.presentation`) of the scan in `store`."""
    from scanner.scan.presentation.hanging import Hanging
    from scanner.scan.presentation.table import Table
    from scanner.scan.presentation.turntable import Turntable

    check_presentation(config.presentation)
    return {k.kind: k for k in (Hanging, Turntable, Table)}[config.presentation](config, store)
