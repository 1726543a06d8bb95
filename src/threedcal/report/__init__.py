"""Study-wide outputs: the results page and the one-page summary (both drawn from the section
builders in threedcal.report.sections), the run environment and the inference speed."""
