"""Studies that reproduce a paper's experiments (not used by the cell): the JSSA simulation
study and its feasibility check (Liu, Chen & Liu 2022)."""
