//! Frame-wise echo extraction for moving listeners (issue 5, item 4).
