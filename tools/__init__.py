"""Lab-bench tools: motion stages (``stages``), the SLM display (``slm``), camera hooks
(``camera``), capture sweeps (``capture``) and the bench configuration (``config``). Vendor SDKs
and GUI libraries are imported lazily, never here."""
