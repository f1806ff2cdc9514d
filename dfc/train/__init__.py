"""Training: one loop (``loop.train``) over a model, a loss, a sampler and a schedule; the data loss
(``losses``), the samplers (``samplers``) and the fitting entry points (``fit``)."""
