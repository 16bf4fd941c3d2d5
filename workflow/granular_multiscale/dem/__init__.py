"""DEM side: YADE RVEs. YADE code lives in modules run inside worker processes only,
because ``from yade import *`` rebinds globals; nothing here imports yade at import time."""
