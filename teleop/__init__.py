"""Recording: the recorder, keyboard teleoperation, parallel workers, and the LeRobot + MCAP writers and readers."""

import logging

# lerobot logs a page-long traceback when torchcodec finds no FFmpeg libraries, then falls back to
# pyav. These datasets hold no video, so the fallback never matters: keep that one logger quiet.
logging.getLogger("lerobot.utils.import_utils").setLevel(logging.ERROR)
