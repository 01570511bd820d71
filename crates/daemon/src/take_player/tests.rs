use super::*;

#[test]
fn only_take_files_in_the_folder_are_opened() {
    let dir = tempfile::tempdir().unwrap();
    let takes = dir.path().join("takes");
    std::fs::create_dir(&takes).unwrap();
    std::fs::write(dir.path().join("secret.mcap"), b"x").unwrap();
    std::fs::write(takes.join("ok_T001.mcap"), b"x").unwrap();
    std::os::unix::fs::symlink(dir.path().join("secret.mcap"), takes.join("link_T001.mcap"))
        .unwrap();
    std::fs::create_dir(takes.join("dir.mcap")).unwrap();
    let folder = TakeFolder::new(&takes);
    assert!(folder.path_of("ok_T001.mcap").is_ok());
    for name in [
        "../secret.mcap",
        "..%2Fsecret.mcap",
        "/etc/passwd",
        "sub/ok_T001.mcap",
        ".hidden.mcap",
        "ok_T001.toml",
        "",
        "a\0.mcap",
    ] {
        assert!(
            matches!(folder.path_of(name), Err(TakeChunkError::BadName(_))),
            "{name:?}: {:?}",
            folder.path_of(name)
        );
    }
    assert!(matches!(
        folder.path_of("link_T001.mcap"),
        Err(TakeChunkError::BadName(_))
    ));
    assert!(matches!(
        folder.path_of("dir.mcap"),
        Err(TakeChunkError::BadName(_))
    ));
    assert!(matches!(
        folder.path_of("missing_T009.mcap"),
        Err(TakeChunkError::NotFound(_))
    ));
    let long = format!("{}.mcap", "a".repeat(300));
    assert!(matches!(
        folder.path_of(&long),
        Err(TakeChunkError::BadName(_))
    ));
}
