"""What every screen uses: worker threads, the camera feed widget, the node views, recent files."""
