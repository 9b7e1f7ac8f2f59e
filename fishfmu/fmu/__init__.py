"""FMUs as files and as running instances: building the built-in ones from their C sources
(``sources/``), checking an archive before anything is loaded from it, running one in-process or in a
worker process."""
