"""Studies that reproduce the paper's comparisons on our data, and their reports."""
