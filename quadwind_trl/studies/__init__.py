"""Studies: measured questions about the library's controllers, each a module with its recipe and its report section."""
