"""The versions of the file formats compd reads and writes, with no import of their schemas.

``compd --version`` prints them without loading pydantic; the schemas
(:mod:`compd.files.modelschema`, :mod:`compd.service.config.docs`) take their
``schema:`` value from here (their pydantic ``Literal`` spells it out for the
type checker; tests/test_helpcomp.py checks the two agree).
"""

from __future__ import annotations

#: The model file's ``schema:`` (:mod:`compd.files.modelschema`).
MODEL_SCHEMA = "compd.model/1"
#: The daemon config's ``schema:`` (:mod:`compd.service.config.docs`).
CONFIG_SCHEMA = "compd.config/1"
