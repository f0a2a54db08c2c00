"""Lab-bench tools (SLM upload, motion stages). Vendor SDKs are imported lazily, never here."""
