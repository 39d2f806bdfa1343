"""The application layer: whole jobs (embed, score, …) built from core, data_formats and recorder."""
