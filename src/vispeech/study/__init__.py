"""A perceptual study of speech animation: its configuration (``STUDY.toml``), the web app
that runs it, its answers in SQLite, and their analysis (cumulative-link mixed models, as the
thesis judged its avatars)."""
