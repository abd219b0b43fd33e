"""``surveil audit``: one self-contained HTML page per window, every chart from the SQL
reports, every requirement of ``[requirements]`` judged (docs/audit.md)."""
