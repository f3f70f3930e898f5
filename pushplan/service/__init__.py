"""``pushplan serve``: planning sessions over gRPC (docs/service.md).  :mod:`.server` routes
calls and enforces the limits; :mod:`.worker` is one session's process.  The client is
:mod:`pushplan.client`."""
