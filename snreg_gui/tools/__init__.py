"""Developer tools around the app: the GUI-thread stall bench and the screenshot script."""
