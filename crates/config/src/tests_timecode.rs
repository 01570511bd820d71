//! `[timecode]`: the host's time of day or LTC from a channel of `[audio]`, checked against
//! that table, with file, line and key in every error.

use super::*;

fn parse(text: &str) -> Result<Config, ConfigError> {
    Config::parse(text, Path::new("/etc/mouthpiece/test.toml"))
}

const AUDIO_2CH: &str = "[audio]\ndevice = \"hw:1,0\"\nchannels = 2\n";

#[test]
fn ltc_is_read_from_a_channel_of_the_audio_device() {
    let config = parse(&format!(
        "{AUDIO_2CH}[timecode]\nrate = \"25\"\nsource = \"ltc\"\nchannel = 2\n"
    ))
    .unwrap();
    assert_eq!(config.timecode.source, TimecodeSource::Ltc);
    assert_eq!(config.timecode.channel, Some(2));
    assert!(
        config.summary().contains("25 from LTC on audio channel 2"),
        "{}",
        config.summary()
    );
    // The default is the host's time of day.
    assert_eq!(parse("").unwrap().timecode.source, TimecodeSource::System);
    for rate in LTC_RATES {
        parse(&format!(
            "{AUDIO_2CH}[timecode]\nrate = \"{rate}\"\nsource = \"ltc\"\nchannel = 2\n"
        ))
        .unwrap();
    }
}

#[test]
fn bad_ltc_settings_name_file_line_and_key() {
    let cases: [(&str, &str, &str, &str); 7] = [
        (
            "[timecode]\nsource = \"gps\"\n",
            "timecode.source",
            ":2:",
            "unknown variant `gps`",
        ),
        (
            "[timecode]\nsource = \"ltc\"\nchannel = 2\n",
            "timecode.source",
            ":2:",
            "expected an [audio] table",
        ),
        (
            "[audio]\nchannels = 2\n[timecode]\nsource = \"ltc\"\n",
            "timecode.source",
            ":4:",
            "expected timecode.channel too",
        ),
        (
            "[audio]\nchannels = 2\n[timecode]\nsource = \"ltc\"\nchannel = 3\n",
            "timecode.channel",
            ":5:",
            "expected 2 to 2",
        ),
        (
            "[audio]\nchannels = 2\n[timecode]\nsource = \"ltc\"\nchannel = 1\n",
            "timecode.channel",
            ":5:",
            "channel 1 is the microphone",
        ),
        (
            "[audio]\n[timecode]\nsource = \"ltc\"\nchannel = 2\n",
            "timecode.channel",
            ":4:",
            "set audio.channels = 2",
        ),
        (
            "[audio]\nchannels = 2\n[timecode]\nrate = \"50\"\nsource = \"ltc\"\nchannel = 2\n",
            "timecode.rate",
            ":4:",
            "expected one of the LTC rates 23.976, 24, 25, 29.97df, 30",
        ),
    ];
    for (text, key, line, message) in cases {
        let err = parse(text).unwrap_err();
        let shown = err.to_string();
        assert_eq!(err.key(), Some(key), "{text}: {shown}");
        assert!(shown.starts_with("/etc/mouthpiece/test.toml"), "{shown}");
        assert!(shown.contains(line), "{text}: {shown}");
        assert!(shown.contains(message), "{text}: {shown}");
    }
    // A channel without LTC is a mistake, not ignored.
    let err = parse("[timecode]\nchannel = 2\n").unwrap_err();
    assert_eq!(err.key(), Some("timecode.channel"), "{err}");
    assert!(err.to_string().contains("source = \"ltc\""), "{err}");
    let err = parse("[timecode]\nsource = \"ltc\"\nchanel = 2\n").unwrap_err();
    assert_eq!(err.key(), Some("timecode.chanel"), "{err}");
}
