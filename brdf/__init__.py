from ._safe import safe_acos as safe_acos, safe_div as safe_div, safe_log as safe_log, safe_normalize as safe_normalize, safe_sqrt as safe_sqrt
