"""The parts of the scaling study (``pmht-opt study scaling``, :mod:`studies.scaling`).

One concept per module: the sizes measured (:mod:`~studies.scaling_study.design`), one child's
measurement of a plan (:mod:`~studies.scaling_study.measure`), medians, slopes and the summary
(:mod:`~studies.scaling_study.summary`), the markdown tables (:mod:`~studies.scaling_study.markdown`)
and the figure (:mod:`~studies.scaling_study.plot`).
"""
