"""A copy of the plant FMU with other parameter start values: a model of its own, with a GUID of
its own (the rig FMUs of ``maglev-cosim fmu --rig``, the calibrated FMUs of the diagnosis and of a
real rig's calibration)."""

from __future__ import annotations

import json
import uuid
import zipfile
from collections.abc import Mapping
from pathlib import Path


#: Namespace of the GUIDs issued to calibrated and rig FMUs (uuid5 of what makes the model).
GUID_NAMESPACE = uuid.UUID("6f1f0e8c-5a3b-4c1e-9b52-ce152a0f0002")


def issued_guid(base_guid: str, parameters: Mapping[str, float], source_sha256: str | None = None) -> str:
    """The GUID of a calibrated FMU: a uuid5 of the nominal FMU's GUID, the start values and the
    hash of the source record, so the same calibration of the same record gets the same GUID."""
    key = json.dumps({"base": base_guid, "parameters": {k: repr(float(v)) for k, v in sorted(parameters.items())},
                      "record_sha256": source_sha256}, sort_keys=True)
    return "{" + str(uuid.uuid5(GUID_NAMESPACE, key)) + "}"


def calibrated_fmu(source: Path, out: Path, parameters: Mapping[str, float], *,
                   resources: Mapping[str, bytes] | None = None, description: str | None = None,
                   model_name: str | None = None, documentation: Mapping[str, bytes] | None = None,
                   source_sha256: str | None = None) -> Path:
    """A copy of the FMU ``source`` whose parameter start values are ``parameters``: a model of its
    own, with a GUID of its own (:func:`issued_guid`, stated in ``resources/guid.txt`` too, the one
    besides its built-in GUID the binary accepts), extra ``resources/`` and ``documentation/`` files
    (FMI 2.0: ``documentation/index.html`` is the entry point) and, when given, another model name
    and description. The ``modelIdentifier`` stays the binary's name."""
    # lxml: imported here, where it is used (fmpy's dependency, not loaded by ``import maglev_cosim``)
    from lxml import etree

    with zipfile.ZipFile(source) as zin:
        root = etree.fromstring(zin.read("modelDescription.xml"))
        lines = ["# start values of this FMU's parameters: the FMU reads them at fmi2Instantiate, so that it",
                 "# uses the start values its modelDescription.xml states (written by maglev-cosim)"]
        for sv in root.iter("ScalarVariable"):
            name = sv.get("name")
            if name in parameters and sv.get("causality") == "parameter":
                real = sv.find("Real")
                real.set("start", repr(float(parameters[name])))
                lines.append(f"{name} {float(parameters[name])!r}")
        guid = issued_guid(root.get("guid"), parameters, source_sha256)
        root.set("guid", guid)
        resources = {"start_values.txt": ("\n".join(lines) + "\n").encode(), "guid.txt": (guid + "\n").encode(),
                     **(resources or {})}
        if description:
            root.set("description", description)
        if model_name:
            root.set("modelName", model_name)
        xml = etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as zout:
            for item in zin.infolist():
                data = xml if item.filename == "modelDescription.xml" else zin.read(item.filename)
                zout.writestr(item, data)
            for folder, files in (("resources", resources), ("documentation", documentation or {})):
                for name, data in files.items():
                    zout.writestr(f"{folder}/{name}", data)
    return out
