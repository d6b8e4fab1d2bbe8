"""Phone inventories (Swedish, English), articulatory features and viseme tables."""
