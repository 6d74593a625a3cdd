"""The video of the static stereo camera watching the cell while the arm moves, with intruders:
what the cell monitor receives, simulated.

intruders.py: the monitored volume and the forearms' paths (geometry); scene.py: the Drake
diagram rendered, with the forearms in it; roi.py: rendering only the window holding some
geometry; masks.py: robot, tool and object masks; video.py: CellFrame and CellVideo (frames,
noise, the clock).
"""
