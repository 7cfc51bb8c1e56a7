%% @doc Internal. Sunrise and sunset for a date and a place, from the
%% sunrise equation NOAA uses (mean anomaly, equation of the centre,
%% ecliptic longitude, solar transit, hour angle with -0.833 degrees for
%% refraction and the sun's radius): good to a couple of minutes.
-module(avatar_sim_sun).

-export([times/2, is_dark/3]).

-export_type([location/0]).

%% Degrees north and east; `utc_offset' in minutes gives local time.
-type location() :: #{lat := number(), lon := number(), utc_offset := integer()}.

%% @doc Sunrise and sunset on local date `Date', in seconds since local
%% midnight. In polar night both are noon; under the midnight sun sunrise is
%% 0 and sunset 86400.
-spec times(calendar:date(), location()) -> {integer(), integer()}.
times(Date, #{lat := Lat, lon := Lon, utc_offset := Offset}) ->
    Days = calendar:date_to_gregorian_days(Date) - calendar:date_to_gregorian_days({2000, 1, 1}),
    N = Days + 0.0008,
    JStar = N - Lon / 360,
    M = fmod(357.5291 + 0.98560028 * JStar, 360),
    C = 1.9148 * sin(M) + 0.0200 * sin(2 * M) + 0.0003 * sin(3 * M),
    Lambda = fmod(M + C + 180 + 102.9372, 360),
    Transit = 2451545.0 + JStar + 0.0053 * sin(M) - 0.0069 * sin(2 * Lambda),
    SinDecl = sin(Lambda) * sin(23.4397),
    CosDecl = math:sqrt(1 - SinDecl * SinDecl),
    CosW = (sin(-0.833) - sin(Lat) * SinDecl) / (cos(Lat) * CosDecl),
    case CosW of
        _ when CosW > 1 -> {43200, 43200};
        _ when CosW < -1 -> {0, 86400};
        _ ->
            W = math:acos(CosW) * 180 / math:pi(),
            Midnight = calendar:datetime_to_gregorian_seconds({Date, {0, 0, 0}})
                - calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}}),
            Local = fun(J) -> round((J - 2440587.5) * 86400) + Offset * 60 - Midnight end,
            {Local(Transit - W / 360), Local(Transit + W / 360)}
    end.

%% @doc Whether it is dark at `Seconds' after local midnight of `Date'.
-spec is_dark(calendar:date(), non_neg_integer(), location()) -> boolean().
is_dark(Date, Seconds, Location) ->
    {Rise, Set} = times(Date, Location),
    Seconds < Rise orelse Seconds >= Set.

sin(Deg) -> math:sin(Deg * math:pi() / 180).
cos(Deg) -> math:cos(Deg * math:pi() / 180).

fmod(X, Y) ->
    R = math:fmod(X, Y),
    case R < 0 of true -> R + Y; false -> R end.
