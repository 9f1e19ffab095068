"""The viewer: an interactive walkthrough served as a web page (``clraster view``)."""
