"""What is measured on a pile: base forces, contact networks, surfaces and
angles of repose (`analysis`), and the papers' analytic models (`theory`)."""
