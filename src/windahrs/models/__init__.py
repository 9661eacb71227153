"""The additive-quaternion models of the paper's filters (:mod:`.additive`) and the
error-state layout (:mod:`.error_state`). The error-state filters' models are the compiled
core's (:mod:`windahrs.core.predict`, :mod:`windahrs.aid`); :mod:`windahrs.core.linearize`
evaluates them at a given state."""
