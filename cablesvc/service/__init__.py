"""The live service: Zenoh outputs (:mod:`~cablesvc.service.zenoh_io`), message payloads and
encodings (:mod:`~cablesvc.service.messages`) and the daemon (:mod:`~cablesvc.service.daemon`).

Submodules are imported where they are used: ``import cablesvc.service`` loads nothing else.
"""
