"""The students' side: what a learned policy reads (`students.inputs`) and a saved policy as a controller
(`students.learned`)."""
