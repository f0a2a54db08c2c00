"""Phase-only SLM patterns from complex holograms: SGD phase retrieval, double-phase amplitude coding, 8-bit lookup-table quantisation."""
