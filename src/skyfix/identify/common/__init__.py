"""How any method's proposals become an :class:`~skyfix.identify.common.result.Identification`:
verification, the refit, a hypothesis judged, the 4-star search loop, inter-star angles (the
second layer of :mod:`skyfix.identify`; it imports only :mod:`skyfix.identify.catalogue` and
:mod:`skyfix.identify.accept`)."""
