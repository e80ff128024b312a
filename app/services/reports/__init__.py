"""Fleet and engine reports: PDF and Excel files with the plots as images."""
